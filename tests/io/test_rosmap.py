"""Tests for bayesmap.io.rosmap: ROS map_server maps (YAML + PGM), hand-made files with known answers, every error
case, and the real Willow Garage floor plan."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bayesmap.errors import BayesmapError
from bayesmap.geometry.grid import Grid
from bayesmap.io.rosmap import RosMap, encode_pgm, read_pgm, read_rosmap, write_pgm, write_rosmap

WILLOW = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "maps" / "willow-full.pgm"

YAML = """image: {image}
resolution: 0.05
origin: [-1.5, 2.25, 0.0]
negate: 0
occupied_thresh: 0.65
free_thresh: 0.196
"""


def write_map(tmp_path, image, yaml_text=YAML, image_name="m.pgm", **fmt):
    (tmp_path / image_name).write_bytes(encode_pgm(np.asarray(image)))
    y = tmp_path / "m.yaml"
    y.write_text(yaml_text.format(image=image_name, **fmt))
    return y


# --------------------------------------------------------------------------------------------------------------
# PGM


def test_pgm_p5_roundtrip_8_and_16_bit(tmp_path):
    rng = np.random.default_rng(0)
    img8 = rng.integers(0, 256, (7, 5)).astype(np.uint8)
    img16 = rng.integers(0, 65536, (3, 4)).astype(np.uint16)
    write_pgm(tmp_path / "a.pgm", img8)
    write_pgm(tmp_path / "b.pgm", img16)
    a, b = read_pgm(tmp_path / "a.pgm"), read_pgm(tmp_path / "b.pgm")
    assert a.dtype == np.uint8 and a.shape == (7, 5)
    assert b.dtype == np.uint16 and b.shape == (3, 4)
    np.testing.assert_array_equal(a, img8)
    np.testing.assert_array_equal(b, img16)
    # 16-bit samples are big-endian: 0x0102 is stored as bytes 01 02
    raw = encode_pgm(np.array([[0x0102]], dtype=np.uint16))
    assert raw.endswith(b"\x01\x02")


def test_pgm_p2_with_comments_everywhere_in_header(tmp_path):
    text = b"P2\n# a comment\n3 # width\n2\n# maxval next\n15\n0 1 2\n# in the raster too\n13 14 15\n"
    (tmp_path / "a.pgm").write_bytes(text)
    np.testing.assert_array_equal(read_pgm(tmp_path / "a.pgm"), [[0, 1, 2], [13, 14, 15]])


def test_pgm_p5_header_comments_and_binary_comment_bytes_in_raster(tmp_path):
    # pixel bytes 35 ('#') and 10 ('\n') are data, not comments, once the header is over
    pixels = bytes([35, 10, 32, 255])
    (tmp_path / "a.pgm").write_bytes(b"P5 # gimp\n# another\n2 2 # size\n255\n" + pixels)
    np.testing.assert_array_equal(read_pgm(tmp_path / "a.pgm"), [[35, 10], [32, 255]])


@pytest.mark.parametrize(
    "data, message",
    [
        (b"P6\n2 2\n255\n" + bytes(12), "not a PGM"),
        (b"\x89PNG\r\n\x1a\n", "not a PGM"),
        (b"P5\n2 2\n255\n\x00\x01\x02", "truncated"),  # 3 of 4 bytes
        (b"P5\n2 2\n65535\n" + bytes(7), "truncated"),  # 16-bit needs 8 bytes
        (b"P5\n2 2", "truncated"),  # header ends before maxval
        (b"P2\n2 2\n255\n1 2 3", "truncated"),
        (b"P2\n2 2\n255\n1 2 x 4", "'x'"),
        (b"P2\n2 2\n9\n1 2 10 4", "value 10 > maxval 9"),
        (b"P5\n2 2\n15\n\x00\x01\x20\x02", "value 32 > maxval 15"),
        (b"P5\n0 2\n255\n", "width '0'"),
        (b"P5\n2 2\n70000\n" + bytes(8), "maxval '70000'"),
        (b"P5\n2 -2\n255\n" + bytes(4), "height '-2'"),
    ],
)
def test_bad_pgm_raises_naming_the_file(tmp_path, data, message):
    path = tmp_path / "bad.pgm"
    path.write_bytes(data)
    with pytest.raises(BayesmapError, match=message) as err:
        read_pgm(path)
    assert str(path) in str(err.value)


def test_missing_pgm_raises(tmp_path):
    with pytest.raises(BayesmapError, match="does not exist"):
        read_pgm(tmp_path / "nope.pgm")


def test_encode_pgm_rejects_bad_images():
    with pytest.raises(BayesmapError, match="2-D"):
        encode_pgm(np.zeros(3, np.uint8))
    with pytest.raises(BayesmapError, match="integer dtype"):
        encode_pgm(np.zeros((2, 2)))
    with pytest.raises(BayesmapError, match="-1"):
        encode_pgm(np.array([[0, -1]]))
    with pytest.raises(BayesmapError, match="300"):
        encode_pgm(np.array([[0, 300]]), maxval=255)


# --------------------------------------------------------------------------------------------------------------
# orientation, occupancy rule, YAML


def test_orientation_top_left_pixel_is_cell_0_topmost(tmp_path):
    # 3 rows x 4 columns, one black (occupied) pixel at the image's top-left, one grey (unknown) at bottom-right
    img = np.full((3, 4), 254, np.uint8)
    img[0, 0] = 0
    img[2, 3] = 205
    m = read_rosmap(write_map(tmp_path, img))
    assert m.grid == Grid(shape=(4, 3), resolution=0.05, origin=(-1.5, 2.25))
    assert m.occupancy.shape == (4, 3) and m.occupancy.dtype == np.float32
    assert np.argwhere(m.walls).tolist() == [[0, 2]]  # top-left pixel -> (0, ny - 1)
    assert np.argwhere(~m.known).tolist() == [[3, 0]]  # bottom-right pixel -> (nx - 1, 0)
    assert m.free.sum() == 10
    # the wall cell's world center: x in the first column, y in the top row
    center = m.grid.cell_centers()[0, 2]
    np.testing.assert_allclose(center, [-1.5 + 0.025, 2.25 + 2.5 * 0.05])


def test_occupancy_rule_and_negate(tmp_path):
    img = np.array([[0, 100, 205, 255]], np.uint8)
    m = read_rosmap(write_map(tmp_path, img))
    np.testing.assert_allclose(m.occupancy[:, 0], (255 - img[0]) / 255, atol=1e-7)
    np.testing.assert_array_equal(m.walls[:, 0], [True, False, False, False])  # 155/255 = 0.608 < 0.65
    np.testing.assert_array_equal(m.free[:, 0], [False, False, False, True])
    neg = read_rosmap(write_map(tmp_path, img, YAML.replace("negate: 0", "negate: 1")))
    np.testing.assert_allclose(neg.occupancy[:, 0], img[0] / 255, atol=1e-7)
    np.testing.assert_array_equal(neg.walls[:, 0], [False, False, True, True])


def test_sixteen_bit_scaled_like_eight_bit(tmp_path):
    img = np.array([[0, 65535, 32768]], np.uint16)
    m = read_rosmap(write_map(tmp_path, img))
    np.testing.assert_allclose(m.occupancy[:, 0], [1.0, 0.0, 32767 / 65535], atol=1e-7)


def test_modes_scale_and_raw(tmp_path):
    img = np.array([[0, 150, 254, 255]], np.uint8)
    scale = read_rosmap(write_map(tmp_path, img, YAML + "mode: scale\n"))
    assert scale.known.all()  # between the thresholds is a graded value, not unknown
    trinary = read_rosmap(write_map(tmp_path, img))
    np.testing.assert_array_equal(trinary.known[:, 0], [True, False, True, True])  # 105/255 = 0.41 is unknown
    raw = read_rosmap(write_map(tmp_path, np.array([[0, 65, 100, 101]], np.uint8), YAML + "mode: raw\n"))
    np.testing.assert_allclose(raw.occupancy[:3, 0], [0.0, 0.65, 1.0], atol=1e-7)
    np.testing.assert_array_equal(raw.known[:, 0], [True, True, True, False])


def test_relative_image_resolved_against_yaml_folder(tmp_path, monkeypatch):
    sub = tmp_path / "maps"
    sub.mkdir()
    (sub / "img").mkdir()
    y = write_map(sub, np.zeros((2, 2), np.uint8), image_name="img/m.pgm")
    monkeypatch.chdir(tmp_path)  # the image is not relative to the working directory
    assert read_rosmap(Path("maps") / y.name).walls.all()
    absolute = YAML.format(image=str(sub / "img" / "m.pgm"))
    (tmp_path / "abs.yaml").write_text(absolute)
    assert read_rosmap(tmp_path / "abs.yaml").walls.all()


def test_bare_pgm_needs_resolution_and_takes_defaults(tmp_path):
    path = tmp_path / "m.pgm"
    write_pgm(path, np.array([[0, 205, 255]], np.uint8))
    with pytest.raises(BayesmapError, match="resolution"):
        read_rosmap(path)
    m = read_rosmap(path, resolution=0.25)
    assert m.grid == Grid(shape=(3, 1), resolution=0.25, origin=(0.0, 0.0))
    assert (m.free_thresh, m.occupied_thresh, m.mode) == (0.196, 0.65, "trinary")
    np.testing.assert_array_equal(m.known[:, 0], [True, False, True])
    assert read_rosmap(path, resolution=1.0, origin=(2, -3)).grid.origin == (2.0, -3.0)


@pytest.mark.parametrize(
    "yaml_text, message",
    [
        (YAML.replace("resolution: 0.05\n", ""), "missing the key resolution"),
        (YAML.replace("negate: 0\n", "").replace("free_thresh: 0.196\n", ""), "missing the keys negate, free_thresh"),
        (YAML.replace("[-1.5, 2.25, 0.0]", "[-1.5, 2.25, 0.3]"), "yaw 0.3 is not supported"),
        (YAML.replace("[-1.5, 2.25, 0.0]", "[-1.5, 2.25]"), "origin must be"),
        (YAML.replace("resolution: 0.05", "resolution: -1"), "resolution must be > 0"),
        (YAML.replace("resolution: 0.05", "resolution: abc"), "resolution must be a finite number"),
        (YAML.replace("negate: 0", "negate: 2"), "negate must be 0 or 1"),
        (YAML.replace("free_thresh: 0.196", "free_thresh: 0.7"), "must be below occupied_thresh"),
        (YAML.replace("occupied_thresh: 0.65", "occupied_thresh: 1.5"), "occupied_thresh must be in"),
        (YAML + "mode: fancy\n", "mode must be one of"),
        ("image: [unclosed\n", "not valid YAML"),
        ("- just\n- a list\n", "YAML mapping"),
        (YAML.replace("{image}", "missing.pgm"), "does not exist"),
    ],
)
def test_bad_yaml_raises_naming_the_file(tmp_path, yaml_text, message):
    y = write_map(tmp_path, np.zeros((2, 2), np.uint8), yaml_text)
    with pytest.raises(BayesmapError, match=message) as err:
        read_rosmap(y)
    assert str(y) in str(err.value)


def test_bad_image_of_yaml_raises_naming_the_image(tmp_path):
    y = write_map(tmp_path, np.zeros((2, 2), np.uint8))
    (tmp_path / "m.pgm").write_bytes(b"P5\n2 2\n255\n\x00")
    with pytest.raises(BayesmapError, match="truncated") as err:
        read_rosmap(y)
    assert str(tmp_path / "m.pgm") in str(err.value)


def test_yaml_with_resolution_argument_is_refused(tmp_path):
    y = write_map(tmp_path, np.zeros((2, 2), np.uint8))
    with pytest.raises(BayesmapError, match="do not pass"):
        read_rosmap(y, resolution=0.1)


def test_rosmap_validates_fields():
    grid = Grid((2, 3))
    with pytest.raises(BayesmapError, match="shape"):
        RosMap(np.zeros((3, 2)), grid)
    with pytest.raises(BayesmapError, match="probabilities"):
        RosMap(np.full((2, 3), 1.5), grid)
    with pytest.raises(BayesmapError, match="mode"):
        RosMap(np.zeros((2, 3)), grid, mode="binary")


# --------------------------------------------------------------------------------------------------------------
# writing


def test_write_read_roundtrip(tmp_path):
    rng = np.random.default_rng(1)
    grid = Grid(shape=(13, 7), resolution=0.05, origin=(-3.2, 1.0e-5))
    occ = rng.random(grid.shape)
    occ[0, 0], occ[1, 0] = 0.0, 1.0
    unknown = rng.random(grid.shape) < 0.2
    unknown[0, 0] = unknown[1, 0] = False
    y = write_rosmap(tmp_path / "out.yaml", occ, grid, unknown=unknown)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.pgm", "out.yaml"]
    assert "mode: trinary" in y.read_text()
    m = read_rosmap(y)
    assert m.grid == grid  # resolution and origin exactly (1e-05 must not come back as a string)
    # each pixel is rint(255 (1 - p)): the read-back probability is within half a grey level
    np.testing.assert_allclose(m.occupancy[~unknown], occ[~unknown], atol=0.5 / 255 + 1e-6)
    assert m.occupancy[0, 0] == 0.0 and m.occupancy[1, 0] == 1.0
    np.testing.assert_array_equal(read_pgm(tmp_path / "out.pgm").T[:, ::-1] == 205, unknown)
    assert not m.known[unknown].any()


def test_write_orientation_matches_ros(tmp_path):
    grid = Grid(shape=(4, 3), resolution=1.0, origin=(0.0, 0.0))
    occ = np.zeros(grid.shape)
    occ[0, 2] = 1.0  # cell (0, ny - 1): the image's top-left pixel
    write_rosmap(tmp_path / "o.yaml", occ, grid)
    img = read_pgm(tmp_path / "o.pgm")
    assert img.shape == (3, 4)
    assert np.argwhere(img == 0).tolist() == [[0, 0]]


def test_write_refuses_to_overwrite_either_file(tmp_path):
    grid = Grid((2, 2))
    occ = np.zeros((2, 2))
    (tmp_path / "a.pgm").write_bytes(b"keep")
    with pytest.raises(BayesmapError, match="a.pgm.*already exists"):
        write_rosmap(tmp_path / "a.yaml", occ, grid)
    assert (tmp_path / "a.pgm").read_bytes() == b"keep" and not (tmp_path / "a.yaml").exists()
    write_rosmap(tmp_path / "b.yaml", occ, grid)
    with pytest.raises(BayesmapError, match="b.yaml.*already exists"):
        write_rosmap(tmp_path / "b.yaml", np.ones((2, 2)), grid)
    assert read_rosmap(tmp_path / "b.yaml").free.all()
    write_rosmap(tmp_path / "b.yaml", np.ones((2, 2)), grid, overwrite=True)
    assert read_rosmap(tmp_path / "b.yaml").walls.all()


def test_write_rejects_bad_input(tmp_path):
    grid = Grid((2, 2))
    with pytest.raises(BayesmapError, match=r"\.yaml"):
        write_rosmap(tmp_path / "a.pgm", np.zeros((2, 2)), grid)
    with pytest.raises(BayesmapError, match="shape"):
        write_rosmap(tmp_path / "a.yaml", np.zeros((3, 2)), grid)
    with pytest.raises(BayesmapError, match=r"cell \(1, 0\) is 1.2"):
        write_rosmap(tmp_path / "a.yaml", np.array([[0, 0], [1.2, 0]]), grid)
    with pytest.raises(BayesmapError, match="nan"):
        write_rosmap(tmp_path / "a.yaml", np.array([[0, 0], [np.nan, 0]]), grid)
    # NaN is fine where the cell is unknown
    write_rosmap(tmp_path / "a.yaml", np.array([[0, 0], [np.nan, 0]]), grid, unknown=np.array([[0, 0], [1, 0]], bool))
    with pytest.raises(BayesmapError, match="free_thresh"):
        write_rosmap(tmp_path / "c.yaml", np.zeros((2, 2)), grid, free_thresh=0.9)
    assert not (tmp_path / "c.yaml").exists() and not (tmp_path / "c.pgm").exists()


# --------------------------------------------------------------------------------------------------------------
# the real Willow Garage floor plan


@pytest.mark.skipif(not WILLOW.exists(), reason="shared data not present")
def test_willow_garage_map():
    img = read_pgm(WILLOW)
    assert img.shape == (587, 540) and img.dtype == np.uint8  # 540 wide, 587 high
    m = read_rosmap(WILLOW, resolution=0.1)
    assert m.grid.shape == (540, 587)
    xmin, xmax, ymin, ymax = m.grid.extent
    np.testing.assert_allclose([xmax - xmin, ymax - ymin], [54.0, 58.7])  # the world file's 54.0 x 58.7 m
    # dark walls, white free space, and grey. NOTE: the grey of this file is 206 (0xCE), not the 205 its README
    # names, and 206 reads as free under map_server's default free_thresh (49/255 = 0.192 < 0.196).
    counts = {v: int((img == v).sum()) for v in (0, 205, 206, 255)}
    assert counts[0] > 1000 and counts[255] > 100_000 and counts[206] > 100_000
    assert counts[205] == 0
    assert m.walls.sum() > 5000 and m.free.sum() > 250_000
