"""Volumetric error maps: grid and axis-table readers, interpolation, conventions, bad input."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.interpolate import RegularGridInterpolator
from scipy.sparse.linalg import spsolve

from ilcnc.errors import InputError, MapError
from ilcnc.vcnc.volumetric import (
    SEED002_CIRCLE_CENTRE_MM,
    SEED002_CIRCLE_RADIUS_MM,
    AxisErrorTables,
    ErrorModel,
    GridMap,
    OutsideMapError,
    SyntheticMap,
    format_grid_csv,
    format_tables_csv,
    load_volumetric,
    seed002_map,
)

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "volumetric"
CONFIGS = ROOT / "configs"

# an affine error field e = A p + b (mm), a few µm over a few hundred mm
A = np.array([[12e-6, -20e-6, 5e-6], [3e-6, -25e-6, 15e-6], [-4e-6, 7e-6, 20e-6]])
B = np.array([1e-3, -2e-3, 0.5e-3])


def _affine(p: NDArray[np.float64]) -> NDArray[np.float64]:
    return p @ A.T + B


def _write_grid(path: Path, xs: NDArray[np.float64], ys: NDArray[np.float64], zs: NDArray[np.float64] | None,
                field: object, *, seed: int = 0) -> Path:
    """A grid CSV (errors in µm), rows shuffled, with comments and a blank line."""
    mesh = np.meshgrid(xs, ys, zs if zs is not None else [0.0], indexing="ij")
    pts = np.column_stack([m.ravel() for m in mesh])
    err = field(pts) * 1e3  # type: ignore[operator]
    rows = np.random.default_rng(seed).permutation(pts.shape[0])
    lines = ["# test grid", "", "x [mm],y [mm]" + (",z [mm]" if zs is not None else "") + ",dx [um],dy [um],dz [um]"]
    for r in rows:
        c = pts[r] if zs is not None else pts[r, :2]
        lines.append(",".join(repr(float(v)) for v in (*c, *err[r])) + "  # node")
    path.write_text("\n".join(lines) + "\n")
    return path


def _inside(n: int, lo: list[float], hi: list[float], seed: int = 1) -> NDArray[np.float64]:
    rng = np.random.default_rng(seed)
    return np.asarray(lo) + rng.random((n, 3)) * (np.asarray(hi) - np.asarray(lo))


# ---------------------------------------------------------------------------
# grid maps
# ---------------------------------------------------------------------------


def test_grid_reproduces_a_linear_field_exactly(tmp_path: Path) -> None:
    xs = np.array([-200.0, -120.0, -10.0, 60.0, 200.0])  # rectilinear, not uniform
    ys = np.array([-150.0, 0.0, 30.0, 150.0])
    zs = np.array([-100.0, -40.0, 20.0])
    path = _write_grid(tmp_path / "grid.csv", xs, ys, zs, _affine)
    grid = load_volumetric(path)
    assert isinstance(grid, GridMap)
    assert grid.dims == 3
    np.testing.assert_array_equal(grid.extent_mm, [[-200, 200], [-150, 150], [-100, 20]])
    p = _inside(2000, [-200, -150, -100], [200, 150, 20])
    np.testing.assert_allclose(grid.error_mm(p), _affine(p), rtol=0, atol=1e-12)
    # nodes, edges and corners exactly
    corners = np.array([[-200, -150, -100], [200, 150, 20], [-10, 30, -40]], dtype=float)
    np.testing.assert_allclose(grid.error_mm(corners), _affine(corners), rtol=0, atol=1e-12)
    # a single point gives a single vector
    assert grid.error_mm(corners[2]).shape == (3,)


def test_grid_units_in_brackets_and_suffixes(tmp_path: Path) -> None:
    text = "x [inch],y_mm,dx_um,dy [mm],dz (nm)\n"
    for x in (0.0, 4.0):
        for y in (0.0, 100.0):
            text += f"{x},{y},{x * 2.0},{y * 1e-5},{y * 10.0}\n"
    grid = load_volumetric(tmp_path_file(tmp_path, "u.csv", text))
    np.testing.assert_allclose(grid.extent_mm[0], [0.0, 101.6])  # 4 inch
    e = grid.error_mm([101.6, 100.0, 0.0])
    np.testing.assert_allclose(e, [8e-3, 1e-3, 1e-3], rtol=1e-12)  # 8 µm, 1e-3 mm, 1000 nm


def tmp_path_file(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_latin1_micro_sign_header(tmp_path: Path) -> None:
    p = tmp_path / "latin1.csv"
    p.write_bytes(b"x,y,dx [\xb5m],dy [\xb5m]\n0,0,0,0\n100,0,1,0\n0,100,0,1\n100,100,1,1\n")
    grid = load_volumetric(p)
    np.testing.assert_allclose(grid.error_mm([100.0, 100.0, 0.0]), [1e-3, 1e-3, 0.0])


def test_two_d_map_serves_any_z(tmp_path: Path) -> None:
    xs, ys = np.linspace(0, 300, 4), np.linspace(0, 200, 3)
    planar = load_volumetric(_write_grid(tmp_path / "xy.csv", xs, ys, None, _affine))
    assert isinstance(planar, GridMap) and planar.dims == 2
    assert np.isinf(planar.extent_mm[2]).all()
    assert "2-D" in planar.describe() and "any Z" in planar.describe()
    p = np.array([[150.0, 50.0, z] for z in (math.nan, -500.0, 0.0, 1000.0)])
    e = planar.error_mm(p)
    want = _affine(np.array([[150.0, 50.0, 0.0]]))[0]
    np.testing.assert_allclose(e, np.tile(want, (4, 1)), atol=1e-12)
    # a z column with a single level is a 2-D map too, measured at that level
    text = "x,y,z,dx [um],dy [um]\n0,0,-5,0,0\n100,0,-5,1,0\n0,100,-5,0,1\n100,100,-5,1,1\n"
    level = load_volumetric(tmp_path_file(tmp_path, "level.csv", text))
    assert isinstance(level, GridMap) and level.dims == 2 and level.z_level_mm == -5.0
    assert "Z=-5 mm" in level.describe()
    np.testing.assert_allclose(level.error_mm([50.0, 50.0, 37.0]), [0.5e-3, 0.5e-3, 0.0])


def test_three_d_map_needs_a_finite_z(tmp_path: Path) -> None:
    path = _write_grid(tmp_path / "g.csv", np.array([0.0, 100.0]), np.array([0.0, 100.0]), np.array([-50.0, 0.0]), _affine)
    grid = load_volumetric(path)
    with pytest.raises(MapError) as exc:
        grid.error_mm([[10.0, 10.0, -1.0], [10.0, 10.0, math.nan]])
    assert str(exc.value) == f"{path}: point #1 has no finite Z coordinate (nan) but the map depends on Z"


def test_cubic_reproduces_a_cubic_field_and_needs_four_nodes(tmp_path: Path) -> None:
    def field(p: NDArray[np.float64]) -> NDArray[np.float64]:
        s = p / 100.0
        return 1e-3 * np.column_stack([s[:, 0] ** 3 - s[:, 1] ** 2, s[:, 0] * s[:, 1], s[:, 1] ** 3])

    xs = np.array([0.0, 30.0, 100.0, 150.0, 200.0])
    ys = np.array([0.0, 40.0, 90.0, 100.0])
    path = _write_grid(tmp_path / "c.csv", xs, ys, None, field)
    p = _inside(500, [0, 0, 0], [200, 100, 0])
    cubic = GridMap.read(path, method="cubic")
    np.testing.assert_allclose(cubic.error_mm(p), field(p), atol=1e-12)
    linear = GridMap.read(path)
    assert np.max(np.abs(linear.error_mm(p) - field(p))) > 1e-5  # linear cannot follow the cubic
    few = _write_grid(tmp_path / "few.csv", xs, ys[:3], None, field)
    with pytest.raises(MapError) as exc:
        GridMap.read(few, method="cubic")
    assert str(exc.value) == f"{few}: method='cubic' needs at least 4 nodes per axis; Y has 3"
    with pytest.raises(ValueError, match="extrapolate='linear' needs method='linear'"):
        GridMap.read(path, method="cubic", extrapolate="linear")


@pytest.mark.parametrize("method", ["linear", "cubic"])
def test_grid_matches_regular_grid_interpolator(method: str) -> None:
    """Same values as scipy's RegularGridInterpolator (cubic: with an exact sparse solve), inside and outside."""
    rng = np.random.default_rng(5)
    axes = (np.array([0.0, 30.0, 100.0, 150.0, 200.0, 260.0]), np.array([-40.0, 0.0, 90.0, 100.0]),
            np.array([-8.0, -7.0, -3.0, 0.0, 1.0]))
    vals = rng.normal(0.0, 2e-3, (6, 4, 5, 3))
    kw = {"solver": spsolve} if method == "cubic" else {}
    ref = RegularGridInterpolator(axes, vals, method=method, bounds_error=False, fill_value=None, **kw)
    p = np.asarray([-20.0, -50.0, -9.0]) + rng.random((2000, 3)) * [300.0, 160.0, 11.0]  # partly outside
    ext = "linear" if method == "linear" else "clamp"
    grid = GridMap(axes, vals, method=method, extrapolate=ext)  # type: ignore[arg-type]
    if method == "linear":
        np.testing.assert_allclose(grid.error_mm(p), ref(p), rtol=0, atol=1e-15)
    else:
        inside = np.all((p >= [0.0, -40.0, -8.0]) & (p <= [260.0, 100.0, 1.0]), axis=1)
        np.testing.assert_allclose(grid.error_mm(p[inside]), ref(p[inside]), rtol=0, atol=1e-15)


# ---------------------------------------------------------------------------
# axis tables and the synthetic map
# ---------------------------------------------------------------------------

MODEL = SyntheticMap(
    [(-200.0, 200.0), (-150.0, 250.0), (-120.0, 30.0)],
    pitch_ppm=(30.0, -25.0, 12.0),
    straightness_um={"yx": 4.0, "zx": -2.0, "xy": 3.0, "zy": 1.0, "xz": -1.5, "yz": 2.5},
    squareness_urad={"xy": 20.0, "xz": -12.0, "yz": 8.0},
)


def test_synthetic_map_terms() -> None:
    m = SyntheticMap([(0.0, 400.0), (0.0, 200.0), (-100.0, 0.0)], pitch_ppm=(25.0, 0.0, 0.0), straightness_um={"yx": 4.0})
    # pitch: +25 ppm -> +10 µm at x = 400; bow: 4 µm in Y at mid-travel of X, zero at its ends
    np.testing.assert_allclose(m.error_mm([[400.0, 0.0, 0.0], [200.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
                               [[10e-3, 0.0, 0.0], [5e-3, 4e-3, 0.0], [0.0, 0.0, 0.0]], atol=1e-15)
    assert m.used_axes.tolist() == [True, False, False]
    # an axis the model does not depend on is never outside
    np.testing.assert_allclose(m.error_mm([100.0, 999.0, math.nan]), [2.5e-3, 3e-3, 0.0])


def test_tables_and_grid_from_the_same_model_agree() -> None:
    pos = {"x": np.linspace(-200, 200, 17), "y": np.linspace(-150, 250, 11), "z": np.linspace(-120, 30, 6)}
    tables = MODEL.tables(pos)
    grid = GridMap.sample(MODEL, pos["x"], pos["y"], pos["z"])
    p = _inside(5000, [-200, -150, -120], [200, 250, 30], seed=7)
    et, eg, em = tables.error_mm(p), grid.error_mm(p), MODEL.error_mm(p)
    # linear interpolation of a sum of one-axis functions: both interpolants are the same function
    np.testing.assert_allclose(et, eg, rtol=0, atol=1e-12)
    # both follow the model within the chord error of the bows: b (h/L)^2 per bow
    bound = 1e-3 * sum(abs(MODEL.straightness_um[d + a]) * (1.0 / (pos[a].size - 1)) ** 2
                       for a in "xyz" for d in "xyz" if d != a)
    assert np.max(np.abs(et - em)) <= bound
    assert np.max(np.abs(et - em)) > 0.05 * bound  # and the bows really are there
    # at the nodes, exact
    nodes = np.column_stack([pos["x"][:6], pos["y"][:6], pos["z"][:6]])
    np.testing.assert_allclose(tables.error_mm(nodes), MODEL.error_mm(nodes), atol=1e-15)


def test_csv_round_trip(tmp_path: Path) -> None:
    pos = {"x": np.linspace(-200, 200, 9), "y": np.linspace(-150, 250, 9), "z": np.linspace(-120, 30, 4)}
    tables = MODEL.tables(pos)
    tpath = tmp_path_file(tmp_path, "t.csv", format_tables_csv(tables, comment="made by a test\nsecond line", decimals=6))
    read = load_volumetric(tpath)
    assert isinstance(read, AxisErrorTables)
    assert read.squareness_urad == {"xy": 20.0, "xz": -12.0, "yz": 8.0}
    gpath = tmp_path_file(tmp_path, "g.csv", format_grid_csv(MODEL, pos["x"], pos["y"], pos["z"], decimals=6))
    grid = load_volumetric(gpath)
    assert isinstance(grid, GridMap)
    p = _inside(1000, [-200, -150, -120], [200, 250, 30], seed=3)
    np.testing.assert_allclose(read.error_mm(p), tables.error_mm(p), atol=1e-9)  # 1e-6 µm rounding
    np.testing.assert_allclose(grid.error_mm(p), tables.error_mm(p), atol=1e-9)
    assert tpath.read_text().startswith("# made by a test\n# second line\naxis,pos [mm],ex [um],ey [um],ez [um]\n")


def test_tables_file_layout(tmp_path: Path) -> None:
    text = (
        "# laser + ballbar report\n"
        "axis,position_mm,ex_um,ey_um\n"  # no ez column: zero
        "y,100,0,-2\n"
        "x,100,5,1\n"
        "x,0,0,0\n"  # any order
        "y,0,0,0\n"
        "\n"
        "squareness,xy,10.31324031,arcsec,\n"  # 50 µrad, trailing empty cell allowed
    )
    t = load_volumetric(tmp_path_file(tmp_path, "t.csv", text))
    assert isinstance(t, AxisErrorTables)
    assert t.squareness_urad["xy"] == pytest.approx(50.0, rel=1e-8)
    assert np.isinf(t.extent_mm[2]).all() and not t.used_axes[2]
    # x=50 -> (2.5, 0.5) µm from X, y=100 -> (0, -2) µm from Y, squareness -50e-6 * 100 mm = -5 µm in X
    np.testing.assert_allclose(t.error_mm([50.0, 100.0, math.nan]), [2.5e-3 - 5e-3, 0.5e-3 - 2e-3, 0.0], atol=1e-12)


def test_positioning_error_sign(tmp_path: Path) -> None:
    """ex > 0 in the X table: the tool stands further along +X than commanded."""
    t = load_volumetric(tmp_path_file(tmp_path, "p.csv", "axis,pos,ex [um],ey [um],ez [um]\nx,0,0,0,0\nx,100,3,0,0\n"))
    assert t.error_mm([100.0, 0.0, 0.0])[0] == pytest.approx(3e-3)


# ---------------------------------------------------------------------------
# squareness sign convention
# ---------------------------------------------------------------------------

PLANE_AXES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}


def _square_models(plane: str, s_urad: float, tmp_path: Path) -> list[ErrorModel]:
    synth = SyntheticMap([(-10.0, 110.0)] * 3, squareness_urad={plane: s_urad})
    text = ("axis,pos,ex [um],ey [um],ez [um]\n"
            + "".join(f"{a},{u},0,0,0\n" for a in "xyz" for u in (-10, 110))
            + f"squareness,{plane},{s_urad},urad\n")
    tables = load_volumetric(tmp_path_file(tmp_path, f"sq-{plane}.csv", text))
    grid = GridMap.sample(synth, [-10.0, 110.0], [-10.0, 110.0], [-10.0, 110.0])
    return [synth, tables, grid]


@pytest.mark.parametrize("plane", ["xy", "xz", "yz"])
def test_squareness_moves_the_corners_of_a_square(plane: str, tmp_path: Path) -> None:
    """S > 0: the angle between the positive axes of the plane opens beyond 90°, the far corners lean to -i."""
    i, j = PLANE_AXES[plane]
    s = 50.0  # µrad
    corners = np.zeros((4, 3))
    corners[1, i] = 100.0
    corners[2, [i, j]] = 100.0
    corners[3, j] = 100.0
    for model in _square_models(plane, s, tmp_path):
        actual = corners + model.error_mm(corners)
        moved = actual - corners
        np.testing.assert_allclose(moved[:2], 0.0, atol=1e-15)  # the corners on the i axis stay
        for c in (2, 3):  # the +j corners move by -S * 100 mm along i, nothing else
            want = np.zeros(3)
            want[i] = -s * 1e-6 * 100.0
            np.testing.assert_allclose(moved[c], want, atol=1e-15)
        u, v = actual[1] - actual[0], actual[3] - actual[0]
        angle = math.acos(float(u @ v) / float(np.linalg.norm(u) * np.linalg.norm(v)))
        assert angle - math.pi / 2 == pytest.approx(s * 1e-6, rel=1e-6)


# ---------------------------------------------------------------------------
# outside the map
# ---------------------------------------------------------------------------


def test_outside_the_map_is_an_error_naming_point_and_extent() -> None:
    path = CONFIGS / "volumetric-grid-example.csv"
    grid = load_volumetric(path)
    pts = np.array([[0.0, 0.0, 0.0], [250.0, 10.0, -20.0], [0.0, 0.0, 60.0]])
    with pytest.raises(OutsideMapError) as exc:
        grid.error_mm(pts)
    assert isinstance(exc.value, MapError) and isinstance(exc.value, InputError)
    assert str(exc.value) == (
        f"{path}: point #1 (x=250.0000, y=10.0000, z=-20.0000 mm) is outside the volumetric map "
        "(X -200..200, Y -200..200, Z -150..50 mm); 2 of 3 points are outside: extend the map or allow "
        "extrapolation (extrapolate='clamp' or 'linear')"
    )
    assert (exc.value.file, exc.value.line, exc.value.index, exc.value.count) == (str(path), None, 1, 2)
    assert exc.value.point_mm == (250.0, 10.0, -20.0)
    # on the edge (and within float noise of it) is inside
    edge = np.array([[200.0 + 1e-9, -200.0, 50.0]])
    np.testing.assert_allclose(grid.error_mm(edge), load_volumetric(path).error_mm([[200.0, -200.0, 50.0]]))


@pytest.mark.parametrize("kind", ["grid", "tables", "synthetic"])
def test_extrapolation_modes(kind: str) -> None:
    """True/"clamp" holds the edge value; "linear" continues linearly (exact for a linear map)."""
    model = SyntheticMap([(-200, 200), (-200, 200), (-150, 50)], pitch_ppm=(100 / 3, -25, 20),
                         squareness_urad={"xy": 20, "xz": -10, "yz": 15})

    def make(extrapolate: bool | str) -> ErrorModel:
        if kind == "grid":
            return load_volumetric(CONFIGS / "volumetric-grid-example.csv", extrapolate=extrapolate)
        if kind == "tables":
            return load_volumetric(CONFIGS / "volumetric-squareness-pitch.csv", extrapolate=extrapolate)
        return SyntheticMap(model.travel_mm, pitch_ppm=model.pitch_ppm, squareness_urad=model.squareness_urad,
                            extrapolate=extrapolate)

    out = np.array([[260.0, -230.0, 70.0]])
    edge = np.array([[200.0, -200.0, 50.0]])
    with pytest.raises(OutsideMapError):
        make(False).error_mm(out)
    for mode in (True, "clamp"):
        np.testing.assert_allclose(make(mode).error_mm(out), model.error_mm(edge), atol=2e-7)
    want = SyntheticMap(model.travel_mm, pitch_ppm=model.pitch_ppm, squareness_urad=model.squareness_urad,
                        extrapolate="linear").error_mm(out)
    np.testing.assert_allclose(make("linear").error_mm(out), want, atol=2e-7)
    assert np.max(np.abs(want - model.error_mm(edge))) > 1e-3  # the two modes differ here


# ---------------------------------------------------------------------------
# shipped sample maps and seed 002
# ---------------------------------------------------------------------------


def test_shipped_sample_maps_describe_the_same_machine() -> None:
    tables = load_volumetric(CONFIGS / "volumetric-squareness-pitch.csv")
    grid = load_volumetric(CONFIGS / "volumetric-grid-example.csv")
    assert isinstance(tables, AxisErrorTables) and isinstance(grid, GridMap)
    assert tables.squareness_urad == {"xy": 20.0, "xz": -10.0, "yz": 15.0}
    np.testing.assert_array_equal(tables.extent_mm, grid.extent_mm)
    np.testing.assert_array_equal(grid.extent_mm, [[-200, 200], [-200, 200], [-150, 50]])
    model = SyntheticMap([(-200, 200), (-200, 200), (-150, 50)], pitch_ppm=(100 / 3, -25, 20),
                         squareness_urad={"xy": 20, "xz": -10, "yz": 15})
    p = _inside(3000, [-200, -200, -150], [200, 200, 50], seed=11)
    np.testing.assert_allclose(tables.error_mm(p), model.error_mm(p), atol=2e-7)  # values rounded to 0.1 nm
    np.testing.assert_allclose(grid.error_mm(p), model.error_mm(p), atol=2e-7)
    # pitch ~10 µm per 300 mm
    assert tables.error_mm([150.0, 0.0, 0.0])[0] - tables.error_mm([-150.0, 0.0, 0.0])[0] == pytest.approx(0.01, abs=2e-7)
    for m in (tables, grid):
        assert "volumetric-" in m.describe() and "X -200..200" in m.describe()


def test_seed002_circle_and_p_type_learning() -> None:
    """Seed 002's case: a circle of R 100 on a map of a few µm; u += gamma * (desired - actual) converges."""
    m = seed002_map()
    np.testing.assert_array_equal(m.extent_mm[0], [0.0, 405.0])
    t = np.linspace(0.0, 2.0 * math.pi, 11)  # 10 parts -> 11 command points, as in the paper
    cx, cy, cz = SEED002_CIRCLE_CENTRE_MM
    desired = np.column_stack([cx + SEED002_CIRCLE_RADIUS_MM * np.cos(t), cy + SEED002_CIRCLE_RADIUS_MM * np.sin(t),
                               np.full(t.size, cz)])
    e0 = m.error_mm(desired)
    peak_um = 1e3 * np.max(np.linalg.norm(e0, axis=1))
    assert 1.0 < peak_um < 10.0
    u = desired.copy()
    norms = []
    for _ in range(4):
        e = desired - (u + m.error_mm(u))  # e = desired - actual (DESIGN.md: not actual - nominal)
        norms.append(float(np.linalg.norm(e)))
        u = u + 1.0 * e
    assert norms[0] == pytest.approx(float(np.linalg.norm(e0)))
    assert all(b < 1e-3 * a for a, b in itertools.pairwise(norms) if a > 1e-12)


# ---------------------------------------------------------------------------
# bad input: every problem names the file and the line
# ---------------------------------------------------------------------------

BAD = [
    ("grid_holes.csv", 4, "grid has 1 hole(s): no node at x=50, y=50, z=0 mm (3 x 3 x 1 = 9 nodes expected, 8 found;"
                          " the first hole is next to the node on this line)"),
    ("grid_duplicate.csv", 5, "duplicate grid node x=100, y=0, z=0 mm (first on line 3)"),
    ("grid_irregular.csv", 9, "irregular grid: x = 50.001 mm is only 0.001 mm from the grid line x = 50 mm"),
    ("grid_nan.csv", 5, "dy is not a finite number (nan)"),
    ("grid_units.csv", 6, "dx = 2.5 mm is larger than max_error_mm = 1 mm: values look like µm: add [um] to the header"),
    ("grid_short_row.csv", 3, "expected 4 columns (x,y,dx [um],dy [um]), got 3"),
    ("grid_bad_number.csv", 4, "y: '1OO' is not a number"),
    ("grid_single_x.csv", None, "the map has a single X position (x = 0 mm): a grid needs at least 2 X values"),
    ("grid_unknown_unit.csv", 1, "unknown unit 'furlong' in column 'dx [furlong]'"),
    ("not_a_map.csv", 2, "not a volumetric map header: expected x,y,z,dx,dy,dz (grid) or axis,pos,ex,ey,ez"),
    ("tables_duplicate.csv", 7, "axis X position 100 mm given twice (first on line 3)"),
    ("tables_units.csv", 4, "ex = 3.2 mm is larger than max_error_mm = 1 mm: values look like µm: add [um] to the header"),
    ("tables_squareness_no_unit.csv", 4, "a squareness row is squareness,<xy|xz|yz>,<value>,<unit>"),
    ("tables_squareness_twice.csv", 5, "squareness xy given twice (first on line 4)"),
    ("tables_squareness_too_big.csv", 5, "squareness xy = 2e+07 µrad is more than 1 mm/m: check its unit"),
    ("tables_bad_axis.csv", 4, "axis 'w' is not x, y, z or squareness"),
    ("tables_one_position.csv", 4, "axis Y has 1 position(s); linear interpolation needs at least 2"),
]


@pytest.mark.parametrize(("name", "line", "problem"), BAD, ids=[b[0] for b in BAD])
def test_bad_map_names_file_line_and_problem(name: str, line: int | None, problem: str) -> None:
    path = DATA / name
    with pytest.raises(MapError) as exc:
        load_volumetric(path)
    where = f"{path}:{line}" if line is not None else f"{path}"
    assert str(exc.value).startswith(f"{where}: {problem}")
    assert (exc.value.file, exc.value.line) == (str(path), line)


def test_unit_given_but_still_too_large(tmp_path: Path) -> None:
    p = tmp_path_file(tmp_path, "mm.csv", "x,y,dx [mm],dy [mm]\n0,0,0,0\n100,0,0,0\n0,100,0,0\n100,100,1.5,0\n")
    with pytest.raises(MapError) as exc:
        load_volumetric(p)
    assert str(exc.value) == (f"{p}:5: dx = 1.5 mm is larger than max_error_mm = 1 mm: "
                              "check the unit in the header ('dx [mm]') or raise max_error_mm")
    assert load_volumetric(p, max_error_mm=2.0).error_mm([100.0, 100.0, 0.0])[0] == pytest.approx(1.5)


def test_more_bad_files(tmp_path: Path) -> None:
    empty = tmp_path_file(tmp_path, "empty.csv", "# nothing\n\n")
    with pytest.raises(MapError, match=r"empty\.csv: empty volumetric map \(no header\)$"):
        load_volumetric(empty)
    header_only = tmp_path_file(tmp_path, "h.csv", "x,y,dx,dy\n")
    with pytest.raises(MapError, match=r"h\.csv: grid map has a header but no rows$"):
        load_volumetric(header_only)
    lacking = tmp_path_file(tmp_path, "l.csv", "x,y,dx\n0,0,0\n")
    with pytest.raises(MapError, match=r"l\.csv:1: grid map header lacks dy \(expected x,y,z,dx,dy,dz\)$"):
        load_volumetric(lacking)
    inf = tmp_path_file(tmp_path, "inf.csv", "axis,pos,ex,ey\nx,0,0,0\nx,inf,0,0\n")
    with pytest.raises(MapError, match=r"inf\.csv:3: pos is not a finite number \(inf\)$"):
        load_volumetric(inf)
    empty_cell = tmp_path_file(tmp_path, "cell.csv", "x,y,dx,dy\n0,0,,0\n")
    with pytest.raises(MapError, match=r"cell\.csv:2: dx is empty$"):
        load_volumetric(empty_cell)
    with pytest.raises(InputError, match="file not found"):
        load_volumetric(tmp_path / "missing.csv")


def test_api_misuse_is_a_value_error() -> None:
    m = seed002_map()
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        m.error_mm(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="extrapolate must be"):
        seed002_map(extrapolate="sometimes")
    with pytest.raises(ValueError, match="strictly increasing"):
        GridMap([[0.0, 0.0], [0.0, 1.0]], np.zeros((2, 2, 3)))
    with pytest.raises(ValueError, match="unknown squareness plane"):
        AxisErrorTables({}, {"xw": 1.0})
    assert m.error_mm(np.zeros((0, 3))).shape == (0, 3)
