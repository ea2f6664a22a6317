"""The posterior map out (bayesmap.io.maps_out, bayesmap.io.rosbag's OccupancyGrid, `infer --maps --out-bag`): each
output is read back with the one line the README gives, and its cells land where bayesmap's (i along x) are."""

import numpy as np
import pytest
import yaml
from PIL import Image

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.io import maps_out
from bayesmap.io.maps_out import encode_png16, encode_posterior_npz, posterior_std, read_png16, seen_cells
from bayesmap.io.rosbag import occupancy_grid_data, read_occupancy_grid_bag, write_occupancy_grid_bag
from helpers import room_scans, run_cli

GRID = Grid((5, 3), 0.25, (-1.5, 2.0))  # not square: a transposed array would not fit


def _probability():
    p = np.linspace(0.0, 1.0, 15).reshape(5, 3)
    p[4, 0] = 0.9  # a marked cell: x index 4 (the largest x), y index 0 (the smallest y)
    return p


def test_std_is_the_bernoulli_standard_deviation():
    np.testing.assert_allclose(posterior_std([[0.0, 0.5, 1.0, 0.1]]), [[0.0, 0.5, 0.0, 0.3]], atol=1e-12)
    with pytest.raises(BayesmapError, match=r"cell \(0, 1\) is 1.5"):
        posterior_std([[0.2, 1.5]])


def test_seen_cells_along_a_path_is_seen_cells_of_its_table_in_any_chunks(monkeypatch):
    """The cells the beams of scans at given poses crossed, built a few rays at a time: those of the scans' one
    ray-cell table (the three scans of a 12 x 9 room, each ray chunk smaller than a scan)."""
    problem = room_scans("beam")
    poses, angles, readings = problem.poses, problem.observations.beam_angles, problem.observations.readings
    whole = seen_cells(problem.table, problem.ray_readings)
    assert whole.any() and not whole.all()
    for chunk in (10_000, 30, 7):  # one table; scans one by one; 7 rays: still one scan per table
        monkeypatch.setattr(maps_out, "SEEN_CHUNK_RAYS", chunk)
        along = maps_out.seen_cells_along(problem.grid, poses, angles, readings, float(problem.params.max_range))
        np.testing.assert_array_equal(along, whole)
    with pytest.raises(BayesmapError, match="must agree"):
        maps_out.seen_cells_along(problem.grid, poses[:2], angles, readings, 15.0)


def test_npz_holds_probability_std_seen_and_the_grid(tmp_path):
    p = _probability()
    seen = p > 0.2
    (tmp_path / "posterior.npz").write_bytes(encode_posterior_npz(p, GRID, seen))
    m = np.load(tmp_path / "posterior.npz")
    assert m["probability"].dtype == np.float32 and m["std"].dtype == np.float32
    np.testing.assert_array_equal(m["probability"], p.astype(np.float32))
    np.testing.assert_allclose(m["std"], np.sqrt(p * (1 - p)), atol=1e-7)
    np.testing.assert_array_equal(m["seen"], seen)
    assert float(m["resolution"]) == 0.25 and list(m["origin"]) == [-1.5, 2.0] and list(m["shape"]) == [5, 3]
    with pytest.raises(BayesmapError, match="grid"):
        encode_posterior_npz(p.T, GRID)


def test_png16_is_a_map_server_image_with_its_yaml(tmp_path):
    p = _probability()
    for name, data in encode_png16("probability", p, GRID, "probability").items():
        (tmp_path / name).write_bytes(data)
    with Image.open(tmp_path / "probability.png") as img:
        assert img.mode.startswith("I") and img.size == (5, 3)  # width = cells along x
        pixels = np.asarray(img)
    assert pixels[-1, -1] == round(0.9 * 65535)  # bottom row = smallest y; last column = largest x
    meta = yaml.safe_load((tmp_path / "probability.yaml").read_text())
    assert meta["image"] == "probability.png" and meta["resolution"] == 0.25 and meta["origin"] == [-1.5, 2.0, 0.0]
    assert meta["value_scale"] == pytest.approx(1 / 65535) and meta["negate"] == 1
    values, grid = read_png16(tmp_path / "probability.yaml")
    np.testing.assert_allclose(values, p, atol=0.5 / 65535 + 1e-12)  # 16-bit quantization
    assert grid == GRID
    # the README's line
    loaded = np.asarray(Image.open(tmp_path / "probability.png"))[::-1].T / 65535
    np.testing.assert_allclose(loaded, p, atol=0.5 / 65535 + 1e-12)


@pytest.mark.parametrize("name", ["map.bag", "map-ros2"])
def test_occupancy_grid_bag_is_percent_with_unknown_cells_and_x_fastest(tmp_path, name):
    p = _probability()
    seen = np.ones(p.shape, bool)
    seen[0, 2] = False
    data = occupancy_grid_data(p, seen)
    assert data.dtype == np.int8 and data[4] == 90  # row 0 (y index 0), column 4 (x index 4): x fastest
    assert data[2 * 5 + 0] == -1
    write_occupancy_grid_bag(tmp_path / name, p, GRID, seen)
    values, grid = read_occupancy_grid_bag(tmp_path / name)
    assert grid == GRID
    np.testing.assert_array_equal(values, np.where(seen, np.rint(100 * p), -1))
    with pytest.raises(BayesmapError, match="already exists"):
        write_occupancy_grid_bag(tmp_path / name, p, GRID, seen)


def test_infer_maps_and_out_bag_write_the_posterior_in_every_form(tmp_path, monkeypatch, capsys):
    (tmp_path / "room.txt").write_text("XXXXXXX\nX.....X\nX..X..X\nX.....X\nXXXXXXX\n")
    args = ["infer", "--map", tmp_path / "room.txt", "--sweeps", 20, "--num-angles", 60, "--out", tmp_path / "out",
            "--maps", "--rosmap", "--out-bag", tmp_path / "map.bag"]
    code, out, err = run_cli(monkeypatch, capsys, *args)
    assert code == 0, err
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert names == ["map.pgm", "map.yaml", "posterior.npy", "posterior.npz", "posterior.png", "probability.png",
                     "probability.yaml", "readings.npy", "std.png", "std.yaml", "summary.json"]
    posterior = np.load(tmp_path / "out" / "posterior.npy")
    m = np.load(tmp_path / "out" / "posterior.npz")
    np.testing.assert_array_equal(m["probability"], posterior)
    np.testing.assert_allclose(m["std"], np.sqrt(posterior * (1 - posterior)), atol=1e-6)
    assert m["seen"].sum() > 0 and not m["seen"].all()  # the beams stop at the walls: cells behind them are unseen
    assert m["seen"][2, 3]  # the sensor's cell (the map's center)
    std, grid = read_png16(tmp_path / "out" / "std.yaml")
    np.testing.assert_allclose(std, m["std"], atol=1e-4)
    values, grid_bag = read_occupancy_grid_bag(tmp_path / "map.bag")
    assert grid_bag == grid and values.shape == posterior.shape == (5, 7)
    np.testing.assert_array_equal(values, np.where(m["seen"], np.rint(100 * posterior), -1))
    # without --force neither the folder nor the bag is replaced
    code, out, err = run_cli(monkeypatch, capsys, *args)
    assert code == 2 and "already exists" in err
    (tmp_path / "out2").mkdir()
    code, out, err = run_cli(monkeypatch, capsys, *args[:-6], "--out", tmp_path / "out2", "--out-bag",
                             tmp_path / "map.bag")
    assert code == 2 and "map.bag" in err and "already exists" in err
    assert list((tmp_path / "out2").iterdir()) == []
