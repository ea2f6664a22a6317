"""The evaluation drivers pass a progress callback on to the long work they run (the chains, the SLAM stages, the
registrations) and draw nothing themselves."""

from __future__ import annotations

import numpy as np

from bayesmap.io.carmen import read_carmen
from bayesmap.io.rosmap import write_pgm


def stages(seen) -> list[str]:
    """The stages of ``seen`` (Progress reports) in the order they started, and check each ends at its total."""
    names = list(dict.fromkeys(p.stage for p in seen))
    for name in names:
        last = [p for p in seen if p.stage == name][-1]
        assert last.done == last.total, name
    return names


def test_held_out_and_floor_plan_evaluations_report_their_chains_sweeps(small_log, tmp_path, capsys):
    from bayesmap.evaluation.heldout import evaluate_log, evaluate_truth

    seen = []
    evaluate_log(read_carmen(small_log), every=4, resolution=0.2, sweeps=4, progress=seen.append)
    assert stages(seen) == ["sweeps"] and seen[-1].total == 4
    image = np.full((24, 34), 255, np.uint8)  # a 3 m x 2 m room of 0.1 m pixels
    image[[0, -1], :] = 0
    image[:, [0, -1]] = 0
    write_pgm(tmp_path / "room.pgm", image)
    seen.clear()
    evaluate_truth(tmp_path / "room.pgm", resolution=0.1, num_poses=2, num_angles=30, max_range=5.0, sweeps=6,
                   clearance=0.3, progress=seen.append)
    assert stages(seen) == ["sweeps"] and seen[-1].total == 6
    assert capsys.readouterr().err == ""  # no bar of their own


def test_the_slam_map_evaluation_reports_the_slam_run_the_registrations_and_the_reference(small_log):
    """SLAM's stages, the held-out scans' registration into its map, the reference map's sweeps, the registration
    into the reference's: in that order."""
    from bayesmap.evaluation.slammap import evaluate_slam_map

    log = read_carmen(small_log)
    seen = []
    scores = evaluate_slam_map(log, log.poses, every=4, resolution=0.2, reference_sweeps=4, progress=seen.append,
                               rounds=1, burn_in=0, map_sweeps=2, pose_sweeps=2, final_map_sweeps=2)
    assert stages(seen) == ["front end", "round 1/1: map", "round 1/1: poses", "final map", "registration",
                            "sweeps"]
    assert [p.stage for p in seen].count("registration") == 2 * (1 + 3)  # two registrations of the 3 held-out scans
    assert {"slam", "true_poses"} <= set(scores)
