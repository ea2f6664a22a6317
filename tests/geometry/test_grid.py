import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.io.ascii import format_map, load_map, parse_map, save_map, tutorial_map


def test_tutorial_map_follows_the_tutorials_convention():
    walls = tutorial_map()
    assert walls.shape == (21, 21) and walls.dtype == np.float32
    assert walls.sum() == 54
    # line i of the text is walls[i, :]: line 3 is ".XXX..........X......"
    assert list(np.flatnonzero(walls[2])) == [1, 2, 3, 14]
    assert walls[4, 1] == 1 and walls[10, 10] == 0


def test_ascii_round_trip(tmp_path):
    walls = (np.random.default_rng(0).random((5, 7)) < 0.4).astype(np.float32)
    text = format_map(walls)
    assert text.splitlines()[0] == "".join("X" if v else "." for v in walls[0])
    assert np.array_equal(parse_map(text), walls)
    path = save_map(tmp_path / "m.txt", walls)
    assert np.array_equal(load_map(path), walls)


@pytest.mark.parametrize(
    "text, match",
    [
        ("", "empty"),
        ("\n\n", "empty"),
        ("X..\nX.\n", "line 2 has 2 characters"),
        ("X..\nXo.\n", r"unknown character 'o' at line 2, column 2"),
    ],
)
def test_malformed_maps_are_named(text, match):
    with pytest.raises(BayesmapError, match=match):
        parse_map(text)


def test_load_map_errors(tmp_path):
    with pytest.raises(BayesmapError, match="does not exist"):
        load_map(tmp_path / "missing.txt")
    with pytest.raises(BayesmapError, match="is a directory"):
        load_map(tmp_path)
    (tmp_path / "bin").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(BayesmapError, match="not a text file"):
        load_map(tmp_path / "bin")


def test_save_map_never_overwrites_without_asking(tmp_path):
    path = tmp_path / "m.txt"
    path.write_text("mine\n")
    with pytest.raises(BayesmapError, match="already exists"):
        save_map(path, np.ones((2, 2)))
    assert path.read_text() == "mine\n"
    save_map(path, np.ones((2, 2)), overwrite=True)
    assert path.read_text() == "XX\nXX\n"
    assert [p.name for p in tmp_path.iterdir()] == ["m.txt"]  # no temporary file left behind


def test_grid_world_and_cell_coordinates():
    tut = Grid((21, 21))
    assert tut.extent == (-0.5, 20.5, -0.5, 20.5)
    assert np.allclose(tut.cell_centers()[4, 1], [4, 1])
    assert tut.default_max_distance == 42
    g = Grid((30, 20), resolution=0.1, origin=(-3.2, 5.0))
    assert np.allclose(g.cell_centers()[0, 0], [-3.15, 5.05])
    assert np.array_equal(g.cell_index([[-3.15, 5.05], [-0.21, 6.95]]), [[0, 0], [29, 19]])
    assert np.allclose(g.to_cell_coords(np.array([-3.15 + 0.1 * 7, 5.05 + 0.1 * 3])), [7, 3])
    assert g.contains([-3.2, 5.0]) and not g.contains([-3.21, 5.0])


@pytest.mark.parametrize("kwargs, match", [
    (dict(shape=(0, 3)), "shape"),
    (dict(shape=(2.5, 3)), "shape"),
    (dict(shape=(2, 3), resolution=0), "resolution"),
    (dict(shape=(2, 3), resolution=float("nan")), "resolution"),
    (dict(shape=(2, 3), origin=(0, float("inf"))), "origin"),
])
def test_bad_grids(kwargs, match):
    with pytest.raises(BayesmapError, match=match):
        Grid(**kwargs)


def test_check_inside_names_the_position():
    with pytest.raises(BayesmapError, match=r"\(25, 3\) is outside the grid"):
        Grid((21, 21)).check_inside([25, 3])
    with pytest.raises(BayesmapError, match="finite"):
        Grid((21, 21)).check_inside([np.nan, 3])


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([0.05, 0.1, 0.3]))
def test_a_covering_grid_is_a_window_of_one_covering_more(seed, resolution):
    """Two ``covering`` grids of one resolution, the second covering the first's points and more: the first's cells
    are a window of the second's, and ``window`` finds it (each cell's center the same point, to 1e-9 m)."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-30, 30, (20, 2))
    more = np.vstack([points, rng.uniform(-40, 40, (5, 2))])
    sub, grid = Grid.covering(points, resolution, 2.0), Grid.covering(more, resolution, 2.0)
    cells = grid.window(sub)
    np.testing.assert_allclose(grid.cell_centers()[cells], sub.cell_centers(), atol=1e-9)


def test_window_refuses_a_grid_that_is_not_one_by_name():
    grid = Grid((10, 8), 0.1, (0.0, 0.0))
    for sub in (Grid((3, 3), 0.2, (0.0, 0.0)), Grid((3, 3), 0.1, (0.05, 0.0)), Grid((3, 3), 0.1, (-0.1, 0.0)),
                Grid((11, 3), 0.1, (0.0, 0.0))):
        with pytest.raises(BayesmapError, match="grid"):
            grid.window(sub)
    assert grid.window(Grid((3, 2), 0.1, (0.2, 0.5))) == (slice(2, 5), slice(5, 7))
