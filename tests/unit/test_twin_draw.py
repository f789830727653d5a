"""Reality profiles drawn from the stated ranges: valid, seeded, inside the ranges."""

from __future__ import annotations

import yaml

from pipeline.mappings import from_mapping
from pipeline.twin.draw import PROFILE_RANGES, draw_profile, draw_profile_mapping
from pipeline.twin.profile import RealityProfile


def test_drawn_profiles_are_seeded_valid_and_inside_their_ranges():
    assert draw_profile_mapping(7, 2) == draw_profile_mapping(7, 2)
    assert draw_profile_mapping(7, 2) != draw_profile_mapping(8, 2)
    for seed in range(30):
        mapping = draw_profile_mapping(seed, 2)
        # a profile file written from it reads back as the same profile
        profile = from_mapping(RealityProfile, yaml.safe_load(yaml.safe_dump(mapping)), "drawn.yaml")
        assert profile == draw_profile(seed, 2)
        for group, ranges in PROFILE_RANGES.items():
            for key, (low, high) in ranges.items():
                if key in mapping[group]:
                    assert low - 1e-9 <= mapping[group][key] <= high + 1e-9, (group, key)
        assert len(profile.map.box_offsets_m) == 2
        low, high = PROFILE_RANGES["lidar"]["mount_x_m"]
        assert low <= profile.lidar.mount_xy_m[0] <= high
        for sector in profile.lidar.blocked_sectors_rad:
            assert 0.05 <= sector[1] - sector[0] <= 0.6 + 1e-3
