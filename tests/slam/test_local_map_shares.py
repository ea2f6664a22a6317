"""Which scans each front-end step was matched against (scanmatch.local_map_shares): the nearest endpoint's scan,
within the local map's window of travel and the fine field's reach, on scans whose endpoints coincide by
construction."""

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.slam.scanmatch import LOCAL_MAP_DISTANCE, ScanData, local_map_shares


def _scans(ranges, returned, step=0.0):
    """Scans at the origin, heading 0, of 12 beams 0.3 rad apart (0.6 m between endpoints at 2 m, beyond the fine
    field's 0.15 m reach): ``ranges`` ``(S, 12)``; odometry ``step`` meters straight ahead per scan."""
    ranges = np.asarray(ranges, np.float64)
    count = len(ranges)
    angles = np.tile(np.linspace(-1.65, 1.65, 12), (count, 1))
    increments = np.tile([step, 0.0, 0.0], (count - 1, 1))
    return ScanData(angles, ranges, np.asarray(returned, bool), increments,
                    np.tile(np.eye(3) * 1e-4, (count - 1, 1, 1)))


def test_a_scan_shares_its_step_among_the_scans_whose_endpoints_it_meets():
    """Scan 0 returns the first eight beams, scan 1 the last four, scan 2 every beam, all at 2 m: scan 2's endpoints
    lie on scan 0's (8 of 12) and scan 1's (4 of 12). Scan 1 meets none of scan 0's endpoints: its step falls back
    on scan 0, the scan before it. Scan 3 at 2.05 m meets scans 0-2 at 5 cm and the others farther: its nearest
    endpoint is scan 0's or scan 2's for the first eight beams (the first scan in the tree's order wins a tie) and
    scan 1's or scan 2's for the rest; its shares sum to 1 over those."""
    ranges = np.full((4, 12), 2.0)
    ranges[3] = 2.05
    returned = np.ones((4, 12), bool)
    returned[0, 8:] = False
    returned[1, :8] = False
    data = _scans(ranges, returned)
    shares = local_map_shares(np.zeros((4, 3)), data).toarray()
    assert shares.shape == (3, 4)
    np.testing.assert_allclose(shares[0], [1, 0, 0, 0])
    np.testing.assert_allclose(shares[1], [8 / 12, 4 / 12, 0, 0])
    np.testing.assert_allclose(shares.sum(axis=1), 1.0)
    assert np.all(shares[2, 3:] == 0) and shares[2, :3].sum() == pytest.approx(1.0)


def test_a_scan_beyond_the_window_is_not_in_the_local_map():
    """Scan 2 lies on scan 0's endpoints exactly and 5 cm from scan 1's. With no travel every earlier scan is in the
    local map and the nearest, scan 0, takes the step; 6 m of odometry a scan puts scan 0 12 m back, beyond the 10 m
    window, and scan 1 takes it. A scan that meets nothing of its local map, its endpoints farther than the reach,
    falls back on the scan before."""
    ranges = np.array([np.full(12, 2.0), np.full(12, 2.05), np.full(12, 2.0)])
    returned = np.ones((3, 12), bool)
    np.testing.assert_allclose(local_map_shares(np.zeros((3, 3)), _scans(ranges, returned)).toarray()[1],
                               [1, 0, 0])
    assert LOCAL_MAP_DISTANCE == 10.0
    np.testing.assert_allclose(local_map_shares(np.zeros((3, 3)), _scans(ranges, returned, 6.0)).toarray()[1],
                               [0, 1, 0])
    far = ranges.copy()
    far[2] = 3.0
    np.testing.assert_allclose(local_map_shares(np.zeros((3, 3)), _scans(far, returned)).toarray()[1], [0, 1, 0])


def test_local_map_shares_follow_the_poses():
    """Three scans of the same ranges, scan 1 placed 5 m ahead of scan 0: scan 2 placed at scan 1's pose meets scan
    1's endpoints, at scan 0's scan 0's. The shares are computed at the given poses."""
    data = _scans(np.full((3, 12), 2.0), np.ones((3, 12), bool))
    ahead = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    np.testing.assert_allclose(local_map_shares(ahead, data).toarray()[1], [0, 1, 0])
    back = ahead.copy()
    back[2] = 0.0
    np.testing.assert_allclose(local_map_shares(back, data).toarray()[1], [1, 0, 0])


def test_local_map_shares_name_a_bad_argument():
    data = _scans(np.full((3, 12), 2.0), np.ones((3, 12), bool))
    with pytest.raises(BayesmapError, match=r"path must be \(3, 3\)"):
        local_map_shares(np.zeros((2, 3)), data)
    with pytest.raises(BayesmapError, match="radius must be a finite number of meters > 0, got 0"):
        local_map_shares(np.zeros((3, 3)), data, radius=0)
    with pytest.raises(BayesmapError, match="window must be"):
        local_map_shares(np.zeros((3, 3)), data, window=-1.0)
    assert local_map_shares(np.zeros((3, 3)), data, window=None).shape == (2, 3)
