"""The fit report: ``calibration.md`` with the estimates and PNG plots of each fit."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from pipeline.calibration.calibrate import Calibration, Source
from pipeline.calibration.estimates import Estimate
from pipeline.calibration.keys import REAL_LIDAR_KEYS
from pipeline.calibration.lidar import SPECTRUM_OUTLIER_M

LIDAR_PLOT = "lidar_residuals.png"
MOUNT_PLOT = "lidar_mount_yaw.png"
ACTUATION_PLOT = "actuation_fit.png"
ODOMETRY_PLOT = "odometry_drift.png"
SPECTRUM_PLOT = "lidar_residual_spectrum.png"
EXAMPLE_WINDOW_S = 12.0
"""Length of the commanded-vs-achieved window shown."""


def _fmt(x: float | None) -> str:
    if x is None or not math.isfinite(x):
        return "-"
    return f"{x:.4g}"


def _row(key: str, est: Estimate) -> str:
    if not est.ok:
        return f"| `{key}` | unidentifiable | | | {est.reason} |"
    interval = "-" if est.interval is None else f"[{_fmt(est.interval[0])}, {_fmt(est.interval[1])}]"
    value = f"{_fmt(est.value)} {est.unit}" + (" (weak)" if est.weak else "")
    how = f"{est.method}, n = {est.n}" + (f"; {est.reason}" if est.weak else "")
    return f"| `{key}` | {value} | {_fmt(est.std_error)} | {interval} | {how} |"


def source_line(source: Source) -> str:
    """What the report says of one recording: its kind, episodes, world and reality profile where it names them,
    and the first digits of its SHA-256."""
    facts = [source.kind] if source.kind else []
    if source.episodes:
        facts.append(f"{source.episodes} episode{'s' if source.episodes != 1 else ''}")
    if source.session.get("world"):
        facts.append(f"world {source.session['world']}")
    if source.session.get("profile"):
        facts.append(f"reality profile `{source.session['profile']}`")
    if source.sha256:
        facts.append(f"SHA-256 {source.sha256[:16]}")
    return ", ".join(facts) or "no metadata"


def _value(calibration: Calibration, key: str) -> float | None:
    """The tabled value of `key` (what calibration.yaml holds), None where it is not identified."""
    est = calibration.values.get(key)
    return float(est.value) if est is not None and est.ok and est.value is not None else None


def lidar_figure(calibration: Calibration) -> Figure | None:
    """Histogram of the still returns' residuals to the calibrated map, with the noise the table gives drawn over
    it: N(bias, (noise_sigma_m + noise_per_m r)^2) averaged over the residuals' ranges r."""
    fit = calibration.lidar
    bias, sigma = _value(calibration, "lidar.bias_m"), _value(calibration, "lidar.noise_sigma_m")
    if fit is None or len(fit.residuals_m) == 0 or bias is None or sigma is None:
        return None
    per_m = _value(calibration, "lidar.noise_per_m") or 0.0
    r = fit.residuals_m
    ranges = fit.residual_ranges_m if len(fit.residual_ranges_m) == len(r) else np.zeros(len(r))
    pick = np.linspace(0, len(r) - 1, min(len(r), 2000)).round().astype(int)
    sigmas = np.maximum(sigma + per_m * ranges[pick], 1e-6)
    at_median = float(np.median(sigmas))
    lo = min(bias - 5 * at_median, float(np.percentile(r, 0.5)))
    hi = max(bias + 5 * at_median, float(np.percentile(r, 99.5)))
    fig, ax = plt.subplots(figsize=(7, 4))
    shown = r[(r > lo) & (r < hi)]
    ax.hist(shown, bins=100, range=(lo, hi), density=True, color="0.55", label=f"residuals (n = {len(r)})")
    x = np.linspace(lo, hi, 400)
    density = np.mean(
        np.exp(-0.5 * ((x[None, :] - bias) / sigmas[:, None]) ** 2) / (sigmas[:, None] * math.sqrt(2 * math.pi)),
        axis=0,
    )
    # the histogram is normalized over what is shown: the curve over the same share of the returns
    ax.plot(x, density * len(r) / max(len(shown), 1), "C0", label=f"bias {bias:.4g} m, noise {sigma:.4g} m + "
            f"{per_m:.4g} m/m (table)")  # fmt: skip
    ax.axvline(bias, color="C0", lw=0.8, ls=":")
    ax.axvline(0.0, color="k", lw=0.5)
    ax.set_xlabel("measured - cast range in the calibrated map (m)")
    ax.set_ylabel("density (1/m)")
    ax.set_title("Lidar residuals during stationary spans")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def _saved(fig: Figure | None, path: Path) -> bool:
    if fig is None:
        return False
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def plot_lidar(calibration: Calibration, path: Path) -> bool:
    """:func:`lidar_figure` saved to `path`; False when there is nothing to plot."""
    return _saved(lidar_figure(calibration), path)


def plot_residual_spectrum(calibration: Calibration, path: Path) -> bool:
    """Power of the span-mean scan residual over angular frequency against the fitted noise alone."""
    fit = calibration.lidar
    spectrum = fit.residual_spectrum if fit is not None else None
    if spectrum is None or len(spectrum.cycles) == 0:
        return False
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.loglog(spectrum.cycles, np.maximum(spectrum.power_m2, 1e-14), "C0", lw=0.8, label="scan residual")
    ax.loglog(spectrum.cycles, spectrum.noise_m2, "k--", lw=1, label="fitted noise alone")
    ax.set_xlabel("angular frequency (cycles per revolution)")
    ax.set_ylabel("power (m^2 per frequency)")
    ax.set_title(f"Scan residual at the calibrated map and mounting ({spectrum.spans} stationary spans)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def spectrum_lines(calibration: Calibration) -> list[str]:
    """The residual spectrum by octave bands: residual power against the fitted noise alone."""
    fit = calibration.lidar
    spectrum = fit.residual_spectrum if fit is not None else None
    if spectrum is None:
        return []
    lines = [
        "Scan residual spectrum (span-mean residual at the calibrated map, mounting and bias, over the beam angle; "
        f"power summed per octave of angular frequency; {spectrum.left_out} beam means more than "
        f"{SPECTRUM_OUTLIER_M * 100:g} cm off, something not on the map, left out):",
        "",
        "| cycles per revolution | residual power (mm^2) | noise alone (mm^2) | ratio |",
        "|---|---|---|---|",
    ]
    for lo, hi, power, noise in spectrum.bands():
        ratio = power / noise if noise > 0 else float("inf")
        lines.append(f"| {lo}-{hi} | {power * 1e6:.3f} | {noise * 1e6:.3f} | {ratio:.1f} |")
    return lines


def mount_yaw_figure(calibration: Calibration) -> Figure | None:
    """The robust cost of the mounting-yaw search near its minimum, with the tabled mounting yaw."""
    fit = calibration.lidar
    if fit is None or fit.yaw_cost is None:
        return None
    yaw, cost = fit.yaw_cost
    finite = np.isfinite(cost)
    if not finite.any():
        return None
    best = float(yaw[finite][np.argmin(cost[finite])])
    near = finite & (np.abs(yaw - best) < math.radians(3))
    fig, ax = plt.subplots(figsize=(7, 3.5))
    order = np.argsort(yaw[near])
    ax.plot(np.degrees(yaw[near][order]), cost[near][order], ".-", ms=3, label="search over the still scans")
    table = _value(calibration, "lidar.mount_yaw_rad")
    if table is not None:
        shown = best + math.remainder(table - best, 2 * math.pi)  # the table's angle on the search's turn
        ax.axvline(math.degrees(shown), color="C3", label=f"table: {table:.4g} rad ({math.degrees(table):.2f} deg)")
    ax.legend(fontsize=8)
    ax.set_xlabel("mounting yaw (deg)")
    ax.set_ylabel("mean truncated |residual| (m)")
    ax.set_title("Mounting-yaw search")
    fig.tight_layout()
    return fig


def plot_mount_yaw(calibration: Calibration, path: Path) -> bool:
    """:func:`mount_yaw_figure` saved to `path`; False when there is nothing to plot."""
    return _saved(mount_yaw_figure(calibration), path)


def plot_actuation(calibration: Calibration, path: Path) -> bool:
    """Commanded vs achieved velocity with the fitted model over a window; False when there is nothing to plot."""
    fit = calibration.actuation
    if fit is None or fit.example is None:
        return False
    t, achieved, model, command = fit.example
    sel = t <= t[0] + EXAMPLE_WINDOW_S
    fig, axes = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    labels = (("forward speed (m/s)", "linear"), ("yaw rate (rad/s)", "angular"))
    for c, ax in enumerate(axes):
        ax.step(t[sel], command[sel, c], where="post", color="0.5", lw=1, label="commanded")
        ax.plot(t[sel], achieved[sel, c], "C0", lw=1.2, label="achieved (smoothed truth)")
        ax.plot(t[sel], model[sel, c], "C3--", lw=1.2, label="fitted model")
        ax.set_ylabel(labels[c][0])
    axes[0].legend(loc="upper right", fontsize=8)
    axes[1].set_xlabel("time (s)")
    delay, tau = fit.delay_s, fit.time_constant_s
    title = "Actuation: gain x first-order lag of the delayed command"
    if delay.ok and tau.ok:
        title += f" (delay {_fmt(delay.value)} s, tau {_fmt(tau.value)} s)"
    axes[0].set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


RESET_JUMP_M = 0.5
"""An odometry error that jumps by more than this between two samples is a reset inside the stretch: the curve
is broken there, not drawn across."""


def odometry_figure(calibration: Calibration) -> Figure | None:
    """Odometry position error against distance travelled per robot-episode, with the tabled drift_per_m."""
    fit = calibration.odometry
    if fit is None or not fit.episodes:
        return None
    fig, ax = plt.subplots(figsize=(7, 4))
    longest = 0.0
    for e in fit.episodes:
        dist, err = (np.asarray(a, dtype=np.float64) for a in e.error_curve)
        if len(err) > 1:
            jump = np.flatnonzero(np.abs(np.diff(err)) > RESET_JUMP_M) + 1
            dist, err = np.insert(dist, jump, np.nan), np.insert(err, jump, np.nan)
        ax.plot(dist, err, lw=0.8, alpha=0.7)
        longest = max(longest, float(np.nanmax(dist)) if np.isfinite(dist).any() else 0.0)
    drift = _value(calibration, "odometry.drift_per_m")
    if drift is not None and longest > 0:
        d = np.linspace(0, longest, 50)
        ax.plot(d, drift * d, "k--", label=f"drift_per_m x distance ({drift:.4g} per m, table): the random part")
        ax.legend(fontsize=8)
    ax.set_xlabel("distance travelled (m)")
    ax.set_ylabel("odometry position error (m)")
    ax.set_title("Odometry error per robot-episode (wheels' systematic error included)")
    fig.tight_layout()
    return fig


def plot_odometry(calibration: Calibration, path: Path) -> bool:
    """:func:`odometry_figure` saved to `path`; False when there is nothing to plot."""
    return _saved(odometry_figure(calibration), path)


def write_report(calibration: Calibration, out_dir: Path) -> Path:
    """Write ``calibration.md`` and the plots into `out_dir`; the report's path."""
    plots = [
        (LIDAR_PLOT, "Lidar residuals", plot_lidar),
        (MOUNT_PLOT, "Mounting yaw", plot_mount_yaw),
        (SPECTRUM_PLOT, "Scan residual spectrum", plot_residual_spectrum),
        (ACTUATION_PLOT, "Commanded vs achieved velocity", plot_actuation),
        (ODOMETRY_PLOT, "Odometry drift", plot_odometry),
    ]
    lines = [
        f"# Calibration: scenario `{calibration.scenario}`",
        "",
        "Recordings:",
        "",
    ]
    for s in calibration.sources:
        lines.append(f"- `{s.path}`: {source_line(s)}")
    if calibration.pose_source.sentence():
        lines += ["", calibration.pose_source.sentence()[0].upper() + calibration.pose_source.sentence()[1:] + "."]
    lines += ["", "| key | estimate | std. error | 95 % interval | method / reason |", "|---|---|---|---|---|"]
    for key, est in calibration.values.items():
        lines.append(_row(key, est))
    if calibration.effective:
        lines += [
            "",
            "Effective values: the simulator's model stands for several of the robot's properties together.",
            "",
            "| effective value | estimate | std. error | 95 % interval | stands for |",
            "|---|---|---|---|---|",
        ]
        for name, value in calibration.effective.items():
            row = _row(f"effective.{name}", value.estimate).rsplit("|", 2)[0]
            lines.append(f"{row}| {' + '.join(f'`{k}`' for k in value.stands_for)} |")
    ambiguities = calibration.actuation.ambiguities if calibration.actuation else ()
    if ambiguities:
        lines += ["", "Ambiguous: two drive models explain the recording alike.", ""]
        lines += [f"- {a.sentence()}" for a in ambiguities]
    ranges = calibration.randomize_ranges()
    if ranges:
        lines += ["", "Training on this calibration randomizes (per episode, uniform):", ""]
        lines += [f"- `{g}.{k}`: [{lo:g}, {hi:g}]" for g, kv in ranges.items() for k, (lo, hi) in kv.items()]
        lines += [
            "",
            "Each range is its key's 95 % interval widened to at least +-10 % of the value; the actuation keys' "
            "ranges also hold the spread the recorded velocity transitions ask for (the randomization fit in the "
            "notes), and the gains are centred on the simulator's gains with the deadband where the motors were "
            "fitted. A range far wider than the interval is that spread of the robot's behaviour, not uncertainty of "
            "the value.",
        ]
    notes: list[str] = []
    fits = (calibration.lidar, calibration.actuation, calibration.odometry, calibration.network)
    for part in (*fits, calibration.wheels, calibration.clock, calibration.motors, calibration.randomization):
        if part is not None:
            notes += list(part.notes)
    if calibration.actuation is not None and calibration.actuation.residual_rms is not None:
        v, w = calibration.actuation.residual_rms
        notes.append(f"actuation fit residual rms: {v:.4f} m/s, {w:.4f} rad/s")
    for key in REAL_LIDAR_KEYS:
        found = calibration.values.get(f"lidar.{key}")
        if found is not None and found.weak:
            notes.append(
                f"lidar.{key} is weak: not applied to the calibrated world (the simulator keeps params.yaml's value); "
                "a real-sensor property enters it only where its interval is narrower than its value"
            )
    gains = calibration.simulator_gains()
    if gains is not None:
        notes.append(
            f"the simulator gets the deadband with gains ({gains[0]:.3f} linear, {gains[1]:.3f} angular) that move "
            "its body over the recorded commands as the body-velocity fit read it (the fit's gains hold the "
            "deadband); it has no acceleration limit, which its lag and delay absorb"
        )
        notes += [agreement.sentence() for agreement in calibration.gain_agreement()]
    if calibration.odometry is not None and calibration.odometry.component_rms:
        parts = ", ".join(f"{k} {v:.4f}" for k, v in calibration.odometry.component_rms.items())
        notes.append(f"odometry draws, rms per component: {parts}")
    if notes:
        lines += ["", "Data used:", ""] + [f"- {n}" for n in notes]
    for name, title, plot in plots:
        if plot(calibration, out_dir / name):
            lines += ["", f"## {title}", "", f"![{title}]({name})"]
    path = out_dir / "calibration.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
