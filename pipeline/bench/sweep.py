"""A training sweep on Ray: every trial of the matrix is a Ray task; finished trials are never run again.

The driver starts a local Ray instance (``workers`` x ``cpus_per_trial`` CPUs) or joins a cluster at
``address`` (``HOST:PORT`` of its head, or ``ray://HOST:PORT`` of its client server; checked to answer
before anything starts; its every node is asked, by a probe task pinned to it, to import this package and
say which source it has, and a node that cannot or has other source is refused by name before any trial
runs), submits one task per unfinished
trial with ``num_cpus=cpus_per_trial`` and collects them as they finish, printing each trial's progress
lines (forwarded by Ray from the workers) and the sweep's (trials done, elapsed, estimated time left).
What a trial reads from the driver's disk travels with its task: the base settings as a mapping, a
scenario given as a file as its text (a node that lacks the file writes it to a folder of its own).
Each row names the node that ran it (``node_id``). A node that dies takes its running trials with it:
Ray runs them again on the nodes left (system failures are retried, a trial's own error is not), and
the row the driver writes is that run's, so no row is lost or doubled. A trial that fails is reported
and left without a row; the sweep goes on. The rows of every finished trial, this run's and earlier
runs', make the sweep's table: ``results.parquet`` and ``results.csv``. Each row names the commit of the
driver's checkout and the host that ran it; ``sweep.json`` records every run of the sweep (command, commit,
machine, dates, the trials it ran), so a sweep folder committed to git says how its rows were made and a
sweep run again with the same ``--out`` on another machine continues from them.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import socket
import subprocess
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import polars as pl

from pipeline.bench.trials import ROW_FILE, Trial, read_row, run_trial, write_row
from pipeline.errors import MrlError

RESULTS = "results"
"""The table's file stem in the sweep folder (``results.parquet``, ``results.csv``)."""
NODE_RETRIES = 3
"""Times a trial is run again after the node running it died (Ray's system-failure retries)."""
RUNS_FILE = "sweep.json"
"""The sweep folder's record of every run of it: command, commit, machine, dates, trials run."""
ADDRESS_TIMEOUT_S = 5.0
"""How long a cluster's head may take to accept a connection before it counts as not answering."""
RAY_TOKEN_FILE = Path(os.path.expanduser("~")) / ".ray" / "auth_token"
"""Where Ray keeps this machine's token (``ray get-auth-token`` prints it)."""
NODE_CHECK_TIMEOUT_S = 120.0
"""How long a cluster's node may take to import this package and say which source it has."""


class SweepError(MrlError):
    """The sweep cannot start (Ray cannot be reached or started)."""


@dataclass(frozen=True)
class SweepOutcome:
    rows: pl.DataFrame
    ran: int
    skipped: int
    failed: dict[str, str]
    wall_s: float


def trial_folder(out: Path, trial: Trial) -> Path:
    return out / "trials" / trial.name


def _task(
    trial: Trial, base: Mapping[str, Any], folder: str, eval_episodes: int, scenario_text: str | None
) -> dict[str, Any]:
    """One trial on a Ray worker: the row, with the node that ran it."""
    import ray

    scenario_file = _scenario_here(trial.scenario, scenario_text)
    row = run_trial(
        trial, base, Path(folder), eval_episodes, say=lambda line: print(line, flush=True), scenario_file=scenario_file
    )
    node = ray.get_runtime_context().get_node_id()
    return {**row, "node_id": node, "host": socket.gethostname(), "finished_utc": _now()}


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def source_commit() -> str:
    """The git commit of the checkout this package is imported from ("+local changes" where its files, untracked
    ones included, differ from it; "unknown" where the package is not a checkout's own ``pipeline/``, such as an
    installed wheel)."""
    package = Path(__file__).resolve().parents[1]
    root = package.parent

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, timeout=10, check=False)
        except (OSError, subprocess.TimeoutExpired):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    top = git("rev-parse", "--show-toplevel")
    commit = git("rev-parse", "HEAD")
    if not top or not commit or Path(top).resolve() != root or package.name != "pipeline":
        return "unknown"
    changed = git("status", "--porcelain", "--", "pipeline")
    return commit + ("+local changes" if changed else "")


def machine() -> str:
    """This machine in a line: host, architecture, CPUs, Python."""
    return f"{platform.node()} ({platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()})"


def read_runs(out: Path) -> list[dict[str, Any]]:
    """The sweep folder's record of its runs (``sweep.json``; [] where none); SweepError naming the file where it
    is not a list of runs (a merge conflict in a committed folder, an edit by hand)."""
    path = out / RUNS_FILE
    if not path.is_file():
        return []
    try:
        runs = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SweepError(f"sweep: {path}: not readable as JSON ({exc}); mend it or move it aside") from None
    if not isinstance(runs, list) or not all(isinstance(run, dict) for run in runs):
        raise SweepError(f"sweep: {path}: must be a list of runs (mappings); mend it or move it aside")
    return runs


def record_run(out: Path, runs: Sequence[Mapping[str, Any]], entry: Mapping[str, Any]) -> None:
    """Write `runs` and `entry` after them as the sweep folder's record (``sweep.json``), atomically."""
    tmp = out / f".{RUNS_FILE}.{os.getpid()}"
    tmp.write_text(json.dumps([*map(dict, runs), dict(entry)], indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, out / RUNS_FILE)


def _scenario_here(scenario: str, text: str | None) -> Path | None:
    """Where this node reads a scenario given as a file: the file itself where it exists here with the driver's
    text, else a copy of that text in a folder of this node's (None: a bundled scenario)."""
    if text is None:
        return None
    path = Path(scenario)
    try:
        if path.is_file() and path.read_text(encoding="utf-8") == text:
            return path
    except OSError:
        pass
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    copy = Path(tempfile.gettempdir()) / "mrl-sweep-files" / digest / path.name
    if not copy.is_file():
        copy.parent.mkdir(parents=True, exist_ok=True)
        tmp = copy.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(copy)
    return copy


def check_address(address: str, timeout_s: float = ADDRESS_TIMEOUT_S) -> None:
    """SweepError unless a Ray head answers at `address`: ``HOST:PORT`` (its GCS, for a driver on a node of the
    cluster) or ``ray://HOST:PORT`` (its client server, for a driver elsewhere)."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit() or "/" in host:
        raise SweepError(
            f"sweep: --address {address!r}: must be HOST:PORT of a Ray head (ray start --head prints it) or "
            "ray://HOST:PORT of its client server"
        )
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except OSError as exc:
        raise SweepError(
            f"sweep: --address {address}: no Ray head answers there ({exc.strerror or exc}); start one with "
            f"`ray start --head --port={port}` or fix the address"
        ) from None


def package_source() -> str:
    """A digest of this package's source as it runs here: the Python files and bundled scenarios of the folder this
    module was imported from."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.suffix in (".py", ".yaml") and "__pycache__" not in p.parts):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def check_nodes(address: str, timeout_s: float = NODE_CHECK_TIMEOUT_S) -> int:
    """SweepError unless every live node of the connected cluster imports this package with the driver's source
    (a probe task pinned to each node, taking no CPU, so a busy node answers too). Returns the number of nodes."""
    import ray
    from ray.exceptions import RayError, RayTaskError
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    def probe() -> str:  # pickled by value: it reaches a node that lacks the package, and says so
        import pipeline.bench.sweep as here

        return here.package_source()

    task = ray.remote(num_cpus=0, max_retries=0)(probe)
    ours = package_source()
    nodes = [n for n in ray.nodes() if n.get("Alive")]
    refs = {
        task.options(scheduling_strategy=NodeAffinitySchedulingStrategy(node["NodeID"], soft=False)).remote(): node
        for node in nodes
    }
    answered, _ = ray.wait(list(refs), num_returns=len(refs), timeout=timeout_s)  # one deadline for every node
    problems = []
    for ref, node in refs.items():
        where = f"node {node.get('NodeManagerAddress', '?')} ({node['NodeID'][:8]})"
        if ref not in answered:
            problems.append(f"{where} did not answer in {timeout_s:.0f} s")
            continue
        try:
            theirs = ray.get(ref)
        except RayTaskError as exc:  # the probe ran there and raised: the node's own import error
            cause = exc.cause if isinstance(exc.cause, BaseException) else exc
            text = (str(cause).strip().splitlines() or [""])[-1]
            problems.append(f"{where} cannot import this package ({type(cause).__name__}: {text})")
        except RayError as exc:  # the probe did not run there (the node died, cannot take tasks)
            problems.append(f"{where} could not run the check ({type(exc).__name__})")
        else:
            if theirs != ours:
                problems.append(f"{where} has other source of this package (digest {theirs}, the driver's {ours})")
    if problems:
        raise SweepError(
            f"sweep: --address {address}: " + "; ".join(problems) + ": install this package, the driver's version, "
            "on every node (pip install -e . in the same checkout) before any trial runs"
        )
    return len(nodes)


def _scenario_texts(trials: Sequence[Trial]) -> dict[str, str]:
    """The text of every scenario given as a file, read on the driver (it travels with the trials)."""
    texts = {}
    for trial in trials:
        path = Path(trial.scenario)
        if trial.scenario not in texts and path.suffix in (".yaml", ".yml") and path.is_file():
            texts[trial.scenario] = path.read_text(encoding="utf-8")
    return texts


def run_sweep(
    trials: Sequence[Trial],
    base: Mapping[str, Any],
    out: Path,
    eval_episodes: int = 200,
    address: str | None = None,
    workers: int = 1,
    cpus_per_trial: float = 1.0,
    say: Callable[[str], None] = print,
    command: str = "mrl sweep",
) -> SweepOutcome:
    """Run the unfinished `trials` as Ray tasks; the table of all finished ones (see the module's description).
    Each run that trains anything is recorded in ``sweep.json`` (`command`, commit, machine, dates, trials), and
    each row it writes names the commit and the host that made it."""
    for trial in trials:  # every trial's settings are valid before anything starts
        trial.params(base)
    if address:
        check_address(address)
    runs = read_runs(out)  # checked before anything runs
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    pending = [t for t in trials if read_row(trial_folder(out, t), t.digest(base)) is None]
    skipped = len(trials) - len(pending)
    failed: dict[str, str] = {}
    if not pending:
        say(f"sweep: {len(trials)} trials, {skipped} finished before (skipped), 0 to run")
    else:
        _connect(address, workers, cpus_per_trial, say)  # a cluster's every node checked before anything moves
        started, commit, completed = _now(), source_commit(), False
        try:
            _set_aside(out, pending, say)
            say(f"sweep: {len(trials)} trials, {skipped} finished before (skipped), {len(pending)} to run")
            failed = _run_trials(pending, base, out, eval_episodes, cpus_per_trial, say, start, commit)
            completed = True
        finally:
            import ray

            ray.shutdown()
            write_table(out, collect(out, trials, base))
            entry = {
                "command": command,
                "commit": commit,
                "machine": machine(),
                "address": address or f"local Ray, {workers} workers",
                "started_utc": started,
                "finished_utc": _now(),
                "ran": [t.name for t in pending if read_row(trial_folder(out, t), t.digest(base)) is not None],
                "failed": failed,
                "skipped": skipped,
            }
            record_run(out, runs, entry if completed else {**entry, "interrupted": True})
    rows = collect(out, trials, base)
    write_table(out, rows)
    wall = time.perf_counter() - start
    say(f"sweep: {rows.height} of {len(trials)} trials have rows, {len(failed)} failed, {wall:.0f} s")
    return SweepOutcome(rows, len(pending) - len(failed), skipped, failed, wall)


def _set_aside(out: Path, pending: Sequence[Trial], say: Callable[[str], None]) -> None:
    stale = set_aside_stale_rows(out, pending)
    if stale:
        say(
            f"sweep: {len(stale)} rows of other settings set aside (never mixed into this table), as "
            + ", ".join(str(p.relative_to(out)) for p in stale)
        )


def _connect(address: str | None, workers: int, cpus_per_trial: float, say: Callable[[str], None]) -> None:
    """Join the cluster at `address` and check its nodes, or start a local Ray of `workers` x `cpus_per_trial`."""
    # each trial's progress lines differ only in numbers, which Ray's log deduplication would fold into one
    os.environ.setdefault("RAY_DEDUP_LOGS", "0")
    if address:
        _use_token_if_any()  # before Ray reads its settings
    import ray

    try:
        if address:
            ray.init(address=address, log_to_driver=True)
        else:
            ray.init(
                address="local",  # a Ray of its own, even where RAY_ADDRESS or a `ray start` on this machine is found
                num_cpus=max(1, round(workers * cpus_per_trial)),
                include_dashboard=False,
                log_to_driver=True,
                configure_logging=False,
            )
    except Exception as exc:  # Ray's own connection and start-up errors
        text = (str(exc).strip().splitlines() or [type(exc).__name__])[-1]
        hint = (
            "; where the head uses token authentication (`ray start --head` turns it on where its machine has a "
            "token) the driver needs that token: set RAY_AUTH_TOKEN to what `ray get-auth-token` prints there"
            if address
            else ""
        )
        raise SweepError(
            f"sweep: cannot {'reach Ray at ' + address if address else 'start a local Ray'}: {text}{hint}"
        ) from exc
    if address:
        try:
            nodes = check_nodes(address)
            cpus = ray.cluster_resources().get("CPU", 0.0)
            say(f"sweep: cluster at {address}: {nodes} nodes with this package's source, {cpus:g} CPUs")
        except BaseException:
            ray.shutdown()
            raise


def _token_found() -> bool:
    return bool(os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH") or RAY_TOKEN_FILE.is_file())


def _use_token_if_any() -> None:
    """Token authentication for a driver that has a Ray token (``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH`` or
    ``~/.ray/auth_token``) and no ``RAY_AUTH_MODE`` of its own: `ray start --head` (Ray 2.60) turns token
    authentication on where its machine has a token, a head with it refuses a driver not in token mode, and a
    driver in token mode reaches a head with or without it (both tested)."""
    if "RAY_AUTH_MODE" not in os.environ and _token_found():
        os.environ["RAY_AUTH_MODE"] = "token"


def _run_trials(
    pending: Sequence[Trial],
    base: Mapping[str, Any],
    out: Path,
    eval_episodes: int,
    cpus_per_trial: float,
    say: Callable[[str], None],
    start: float,
    commit: str,
) -> dict[str, str]:
    """Submit the `pending` trials to the connected Ray and write their rows (with the driver's `commit`) as they
    come back."""
    import ray

    failed: dict[str, str] = {}
    # a dead node's trials run again elsewhere; a trial's own exception is not retried
    task = ray.remote(num_cpus=cpus_per_trial, max_retries=NODE_RETRIES, retry_exceptions=False)(_task)
    texts = _scenario_texts(pending)
    refs = {
        task.remote(t, dict(base), str(trial_folder(out, t)), eval_episodes, texts.get(t.scenario)): t for t in pending
    }
    done = 0
    while refs:
        ready, _ = ray.wait(list(refs), num_returns=1)
        trial = refs.pop(ready[0])
        done += 1
        try:
            row = {**ray.get(ready[0]), "commit": commit}
            # the row comes back to the driver: on a cluster the trial's node may not share its disk
            folder = trial_folder(out, trial)
            if read_row(folder) != row:
                folder.mkdir(parents=True, exist_ok=True)
                write_row(folder, row)
            what = f"robot success {row['robot_success']:.3f}"
        except Exception as exc:  # a failed trial is reported, the sweep goes on
            failed[trial.name] = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
            what = f"FAILED: {failed[trial.name]}"
        elapsed = time.perf_counter() - start
        left = elapsed / done * (len(pending) - done)
        say(f"sweep: [{done}/{len(pending)}] {trial.name}: {what} ({elapsed:.0f} s elapsed, ~{left:.0f} s left)")
    return failed


def set_aside_stale_rows(out: Path, pending: Sequence[Trial]) -> list[Path]:
    """Rows of `pending` trials finished with other settings (their digest differs), moved to
    ``row.stale-<digest>.json`` beside the trial's folder before the trial runs again: kept, named, never read as
    this sweep's. Returns where they went."""
    moved = []
    for trial in pending:
        folder = trial_folder(out, trial)
        old = read_row(folder)
        if old is None:
            continue
        target = folder / f"row.stale-{old.get('params_digest', 'unknown')}.json"
        (folder / ROW_FILE).replace(target)
        moved.append(target)
    return moved


def collect(out: Path, trials: Sequence[Trial], base: Mapping[str, Any]) -> pl.DataFrame:
    """The rows of the `trials` finished with the settings of `base`, in the trials' order."""
    rows = [row for t in trials if (row := read_row(trial_folder(out, t), t.digest(base))) is not None]
    return pl.DataFrame(rows) if rows else pl.DataFrame()


def write_table(out: Path, rows: pl.DataFrame) -> None:
    if rows.is_empty():
        return
    rows.write_parquet(out / f"{RESULTS}.parquet")
    rows.write_csv(out / f"{RESULTS}.csv")
