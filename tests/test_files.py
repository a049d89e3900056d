"""Files peeljax writes: every kind loads back (pj.load), sweeps and maps as labelled data
(to_xarray, netCDF) with units and the peeljax version, Solution.save, and writes that never
destroy the previous file (peeljax._atomic)."""

from __future__ import annotations

import dataclasses
import errno
import json
import sys

import jax.numpy as jnp
import numpy as np
import pytest

import peeljax as pj
from peeljax import _atomic
from peeljax.solution import Solution, StopReason
from peeljax.sweeps import StickSlipMap
from peeljax.sweeps.stick_slip_map import FOLD_FIELDS, LANE_FIELDS

from conftest import assert_refused, forbid, run_cli

xr = pytest.importorskip("xarray")  # the test extra installs it (peeljax[xarray])

SWEEP = dict(V=[1.1, 2.0], tau=[1e-2, 1e-1], dt=0.01, t_final=0.2, save_every=5, params={"c1": [400.0, 410.0]})


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    """One small sweep (uniform mesh) written to .npz and, with the same compiled program, to .nc."""
    folder = tmp_path_factory.mktemp("sweeps")
    npz, nc = folder / "sweep.npz", folder / "sweep.nc"
    result = pj.sweep(**SWEEP, out=npz, progress=False)
    from_nc = pj.sweep(**SWEEP, out=nc, progress=False)
    return result, from_nc, npz, nc


def _same_arrays(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b)
    for key in a:
        np.testing.assert_array_equal(np.asarray(a[key]), np.asarray(b[key]), err_msg=key)


# ---------------------------------------------------------------------------- sweeps
@pytest.mark.slow  # the module's one sweep: compiling it
def test_a_sweep_written_and_loaded_back_is_the_same_labelled_data(sweeps):
    result, _, npz, _ = sweeps
    loaded = pj.load(npz)
    assert isinstance(loaded, pj.SweepResult) and loaded.grid_shape == result.grid_shape == (2, 2, 2)
    _same_arrays(loaded.arrays(), result.arrays())
    ds = result.to_xarray()
    xr.testing.assert_identical(loaded.to_xarray(), ds)
    assert dict(ds.sizes) == {"V": 2, "tau": 2, "c1": 2, "t": 5}
    np.testing.assert_array_equal(ds["tau"], [1e-2, 1e-1])
    np.testing.assert_array_equal(ds["c1"], [400.0, 410.0])
    # labelled: the lane at V = 2, tau = 0.1, c1 = 410 is the flat lane 7 (C order V x tau x c1)
    assert float(ds["v_mean"].sel(V=2.0, tau=0.1, c1=410.0)) == result.v_mean[7]
    np.testing.assert_array_equal(ds["u"].sel(V=1.1, tau=0.01, c1=400.0), result.ys[0, :, 2])
    units = {name: ds[name].attrs.get("units") for name in (*ds.data_vars, *ds.coords)}
    assert units["V"] == "m/s" and units["tau"] == "s" and units["c1"] == "N (s/m)^p1" and units["t"] == "s"
    assert units["v_mean"] == "m/s" and units["t_stop"] == "s" and units["alpha"] == "rad" and units["u"] == "m"
    no_units = {name for name, unit in units.items() if unit is None}
    assert no_units == {"completed", "status"}  # flags: status carries CF flag_values / flag_meanings
    assert ds["status"].attrs["flag_meanings"].split()[int(StopReason.MAX_STEPS)] == "max_steps"
    assert ds.attrs["kind"] == "sweep" and ds.attrs["peeljax_version"] == pj.__version__
    assert json.loads(ds.attrs["settings_json"]) == json.loads(json.dumps(result.settings))
    assert ds.attrs["t_final"] == 0.2 and ds.attrs["grid"] == "outer"


@pytest.mark.slow  # the module's one sweep: compiling it
def test_the_npz_records_kind_units_and_version(sweeps):
    _, _, npz, _ = sweeps
    with np.load(npz, allow_pickle=False) as data:
        meta = json.loads(str(data["meta_json"]))
    assert meta["kind"] == "sweep" and meta["peeljax_version"] == pj.__version__
    assert meta["units"]["v_mean"] == "m/s" and meta["units"]["param_c1"] == "N (s/m)^p1"
    assert meta["units"]["ys"] == ["rad", "rad/s", "m", "m/s"] and meta["format"] == "peeljax-sweep"


@pytest.mark.slow  # the module's one sweep: compiling it
def test_sweep_out_nc_writes_netcdf_that_loads_and_resumes(sweeps, monkeypatch):
    result, from_nc, _, nc = sweeps
    with xr.open_dataset(nc, engine="h5netcdf") as raw:  # a plain netCDF-4 file, units on disk
        assert raw["v_max"].attrs["units"] == "m/s" and raw.attrs["kind"] == "sweep"
    xr.testing.assert_identical(pj.load(nc).to_xarray(), result.to_xarray())
    _same_arrays(from_nc.arrays(), result.arrays())
    forbid(monkeypatch, "peeljax.sweeps.engine", "run_batch", reason="a finished .nc must be loaded, not rerun")
    again = pj.sweep(**SWEEP, out=nc, progress=False)
    assert again.computed_chunks == ()
    _same_arrays(again.arrays(), result.arrays())
    other = {**SWEEP, "t_final": 0.3}
    with pytest.raises(ValueError, match="different settings"):
        pj.sweep(**other, out=nc, progress=False)


@pytest.mark.slow  # the module's one sweep: compiling it
def test_pairs_and_jump_records_round_trip(sweeps, tmp_path):
    """A grid="pairs" sweep has the dimension trajectory; jump records add the dimension jump."""
    result = sweeps[0]
    n, slots = len(result), 3
    rng = np.random.default_rng(0)
    jumps = {
        "jump_count": np.arange(n) % 4 - (np.arange(n) % 4 == 3),
        "jump_t": rng.random((n, slots)),
        "jump_up": rng.random((n, slots)) > 0.5,
        "jump_v_before": rng.random((n, slots)),
        "jump_v_after": rng.random((n, slots)),
        "jump_G": 250 + rng.random((n, slots)),
    }
    pairs = dataclasses.replace(result, grid_shape=None, settings={**result.settings, "grid": "pairs"}, jumps=jumps)
    ds = pairs.to_xarray()
    assert dict(ds.sizes) == {"trajectory": n, "t": 5, "jump": slots}
    assert ds["jump_G"].attrs["units"] == "N" and ds["jump_up"].dtype == bool
    np.testing.assert_array_equal(ds["c1"], result.params["c1"])  # a coordinate along trajectory
    for name in ("pairs.npz", "pairs.nc"):
        pairs.save(tmp_path / name)
        back = pj.load(tmp_path / name)
        assert back.grid_shape is None
        _same_arrays(back.arrays(), pairs.arrays())
        xr.testing.assert_identical(back.to_xarray(), ds)


@pytest.mark.slow  # the module's one sweep: compiling it
def test_a_sweep_file_from_before_files_named_their_kind_still_loads(sweeps, tmp_path):
    _, _, npz, _ = sweeps
    with np.load(npz, allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    meta = json.loads(str(arrays["meta_json"]))
    old = {key: meta[key] for key in ("format", "version", "settings", "n_chunks")}
    np.savez(tmp_path / "old.npz", **{**arrays, "meta_json": np.asarray(json.dumps(old))})
    loaded = pj.load(tmp_path / "old.npz")
    assert isinstance(loaded, pj.SweepResult) and loaded.peeljax_version is None
    _same_arrays(loaded.arrays(), sweeps[0].arrays())


# ---------------------------------------------------------------------------- stick-slip maps
def _map() -> StickSlipMap:
    """A small map made by hand (2 starts x 3 V, up to 2 jumps a lane): the files, not the runs."""
    rng = np.random.default_rng(1)
    shape = (2, 3)
    ints = ("status", "jumps_total", "jumps", "slips", "crossings", "events", "repeats")
    arrays = {
        "V": np.array([0.5, 1.1, 6.0]),
        "starts": np.array(["paper", "steady"]),
        "tau": np.float64(0.0),
        "t_final": np.float64(3.0),
        "transient": np.float64(1.5),
        "wall_time": np.float64(2.5),
        **{name: (rng.integers(0, 5, shape) if name in ints else rng.random(shape)) for name in LANE_FIELDS},
        "jump_G": np.where(rng.random((*shape, 2)) > 0.3, 250 + rng.random((*shape, 2)), np.nan),
        "jump_up": rng.random((*shape, 2)) > 0.5,
        **{name: np.array([260.0, 255.0, np.nan]) for name in FOLD_FIELDS},
        "settings_json": np.asarray(json.dumps({"transient": 1.5, "repeat_rtol": 1e-3})),
    }
    return StickSlipMap.from_arrays(arrays)


@pytest.mark.parametrize("suffix", [".npz", ".nc"])
def test_a_stick_slip_map_loads_back_labelled(suffix, tmp_path):
    smap = _map()
    ds = smap.to_xarray()
    assert dict(ds.sizes) == {"start": 2, "V": 3, "jump": 2}
    assert ds["G_slip_max"].attrs["units"] == "N" and ds["period"].attrs["units"] == "s"
    assert ds["v_max"].dims == ("V",) and ds["v_max"].attrs["units"] == "m/s"
    assert ds.attrs["kind"] == "stick-slip-map" and ds.attrs["tau"] == 0.0 and ds.attrs["transient_units"] == "s"
    assert list(ds["start"].values) == ["paper", "steady"]
    path = tmp_path / f"map{suffix}"
    smap.save(path)
    back = pj.load(path)
    assert isinstance(back, StickSlipMap)
    _same_arrays(back.as_arrays(), smap.as_arrays())
    xr.testing.assert_identical(back.to_xarray(), ds)
    if suffix == ".npz":
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta_json"]))
        assert meta["kind"] == "stick-slip-map" and meta["units"]["G_slip_min"] == "N"
        arrays = {key: value for key, value in smap.as_arrays().items()}  # as written before: no meta_json
        np.savez(tmp_path / "old_map.npz", **arrays)
        assert isinstance(pj.load(tmp_path / "old_map.npz"), StickSlipMap)


def test_load_refuses_a_kind_it_does_not_know_and_foreign_netcdf(tmp_path):
    path = tmp_path / "future.npz"
    np.savez(path, meta_json=np.asarray(json.dumps({"kind": "hologram"})))
    with pytest.raises(ValueError, match=r"holds a 'hologram', which this peeljax cannot read .*a newer peeljax"):
        pj.load(path)
    foreign = tmp_path / "foreign.nc"
    xr.Dataset({"x": ("a", np.arange(3.0))}).to_netcdf(foreign, engine="h5netcdf")
    with pytest.raises(ValueError, match=r"foreign.nc' is not a netCDF file peeljax wrote: its kind is None"):
        pj.load(foreign)
    (tmp_path / "junk.nc").write_bytes(b"not netcdf at all")
    with pytest.raises(ValueError, match=r"junk.nc' is not a readable netCDF file"):
        pj.load(tmp_path / "junk.nc")


# ---------------------------------------------------------------------------- runs: Solution.save
def _solution() -> Solution:
    ts = jnp.linspace(0.0, 0.1, 11)
    ys = jnp.stack([1e-3 * ts, 10 * ts, 0.3 + 0.01 * ts, 1e-3 + ts], axis=1)
    return Solution(
        ts=ts, ys=ys, valid=jnp.ones(11, bool), status=jnp.asarray(0), t_stop=jnp.asarray(0.1),
        stats={"steps": jnp.asarray(12), "step_size": jnp.asarray(jnp.nan)}, diagnostics=None,
    )  # fmt: skip


def test_solution_save_writes_what_simulate_out_writes(tmp_path):
    from peeljax.cli import build_parser, validate_run, write_npz

    config = validate_run(build_parser().parse_args(["simulate", "--V", "2", "--tau", "0.05", "--t-final", "0.1"]))
    solution = _solution()
    write_npz(str(tmp_path / "cli.npz"), solution, config)
    solution.save(
        tmp_path / "api.npz", model=config.model, V=2.0, tau=0.05, t_final=0.1, rtol=config.rtol, atol=config.atol,
        method_option=config.method, fold=config.fold, max_jumps=config.max_jumps, transient=config.transient,
        rho=config.rho,
    )  # fmt: skip
    with np.load(tmp_path / "cli.npz", allow_pickle=False) as a, np.load(tmp_path / "api.npz") as b:
        _same_arrays(dict(a), dict(b))
        meta = json.loads(str(a["meta_json"]))
    assert meta["kind"] == "run" and meta["units"]["v"] == "m/s" and meta["units"]["F"] == "N"
    run = pj.load(tmp_path / "api.npz")
    assert run.units["t"] == "s" and run.peeljax_version == pj.__version__ and run.V == 2.0
    run.save(tmp_path / "again.npz")  # a SavedRun supplies its own V, tau, model and settings
    with np.load(tmp_path / "api.npz", allow_pickle=False) as a, np.load(tmp_path / "again.npz") as b:
        _same_arrays(dict(a), dict(b))
    with pytest.raises(TypeError, match=r"save needs the run's V"):
        solution.save(tmp_path / "x.npz", tau=0.0)


def test_a_law_that_is_code_is_not_written_as_the_papers_family(tmp_path):
    """A subclass of AdhesionLaw is code (its _evaluate): a run's file names no coefficients
    for it, as for a function, and a sweep's settings hold its class and fields. Before, the
    file held its 14 coefficients and was read back as the paper's φ, another law."""
    from peeljax.adhesion import in_a_file, law_settings

    class ScaledLaw(pj.AdhesionLaw):
        scale: float = 1.0

        def _evaluate(self, v, V):
            return self.scale * super()._evaluate(v, V)

    law = ScaledLaw(scale=1.1)
    assert in_a_file(pj.AdhesionLaw()) and not in_a_file(law) and not in_a_file(lambda v, V: v)
    _solution().save(tmp_path / "run.npz", model=pj.PeelingModel(adhesion=law), V=2.0, tau=0.05, t_final=0.1)
    with np.load(tmp_path / "run.npz", allow_pickle=False) as data:
        assert str(data["phi_json"]) == ""
    assert pj.load(tmp_path / "run.npz").model is None  # φ is not in the file
    settings = law_settings(law)
    assert settings["class"] == "test_a_law_that_is_code_is_not_written_as_the_papers_family.<locals>.ScaledLaw"
    assert settings["scale"] == 1.1 and settings["c1"] == 400.0
    assert law_settings(ScaledLaw(scale=1.2)) != settings and law_settings(pj.AdhesionLaw()) == pj.AdhesionLaw().coefficients()


# ---------------------------------------------------------------------------- atomic writes
class _FullDisk:
    """``open`` whose files take ``room`` bytes and then fail as a full disk does."""

    def __init__(self, room: int):
        self.room = room

    def __call__(self, path, mode="r", **kwargs):
        real = open(path, mode, **kwargs)  # noqa: SIM115 (returned wrapped)
        if "w" not in mode:
            return real
        room = self.room

        class Stream:
            def __init__(self):
                self.written = 0

            def write(self, data):
                if self.written + len(data) > room:
                    real.write(data[: max(0, room - self.written)])
                    raise OSError(errno.ENOSPC, "No space left on device")
                self.written += len(data)
                return real.write(data)

            def __getattr__(self, name):
                return getattr(real, name)

            def __enter__(self):
                return self

            def __exit__(self, *exc):
                real.close()

        return Stream()


def _writers(tmp_path):
    from matplotlib.figure import Figure

    fig = Figure()
    fig.add_subplot().plot([0, 1], [1, 0])
    return {
        "run.npz": lambda p: _solution().save(p, V=1.1, tau=0.0),
        "phi.json": lambda p: pj.AdhesionLaw().to_json(p),
        "figure.png": lambda p: _atomic.save_figure(fig, p, dpi=50),
        "map.npz": lambda p: _map().save(p),
        "table.csv": lambda p: _atomic.write_text(p, "V,F_mean\n" + "1.1,245.0\n" * 500),
    }


@pytest.mark.parametrize("name", ["run.npz", "phi.json", "figure.png", "map.npz", "table.csv"])
def test_a_write_failing_midway_keeps_the_previous_file(name, tmp_path, monkeypatch):
    path = tmp_path / name
    write = _writers(tmp_path)[name]
    write(path)
    before = path.read_bytes()
    monkeypatch.setattr(_atomic, "open", _FullDisk(room=len(before) // 3), raising=False)
    with pytest.raises(OSError, match="No space left on device"):
        write(path)
    assert path.read_bytes() == before  # the previous file, as it was
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # and no partial file left behind
    monkeypatch.undo()
    path.unlink()
    write(path)  # a new file gets the mode a plain open gives it
    import os

    mask = os.umask(0o022)
    os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask


def test_a_netcdf_write_failing_midway_keeps_the_previous_file(tmp_path, monkeypatch):
    smap = _map()
    path = tmp_path / "map.nc"
    smap.save(path)
    before = path.read_bytes()

    def fail_midway(self, target, **kwargs):
        with open(target, "wb") as stream:
            stream.write(before[: len(before) // 2])
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(xr.Dataset, "to_netcdf", fail_midway)
    with pytest.raises(OSError, match="No space left"):
        smap.save(path)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["map.nc"]


def test_ctrl_c_during_a_write_keeps_the_previous_file(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("previous")
    with pytest.raises(KeyboardInterrupt), _atomic.replacing(path) as temporary:
        temporary.write_text("half")
        raise KeyboardInterrupt
    assert path.read_text() == "previous" and [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_a_symlink_is_followed_and_a_device_written_in_place(tmp_path):
    target = tmp_path / "real.txt"
    target.write_text("old")
    link = tmp_path / "link.txt"
    link.symlink_to(target)
    _atomic.write_text(link, "new")
    assert link.is_symlink() and target.read_text() == "new"
    _atomic.write_text("/dev/null", "nothing")  # not replaced by a regular file
    import stat

    assert stat.S_ISCHR(__import__("os").stat("/dev/null").st_mode)


# ---------------------------------------------------------------------------- without the extra
def test_without_xarray_the_message_says_how_to_install_it(monkeypatch, no_compilation, tmp_path):
    monkeypatch.setitem(sys.modules, "xarray", None)  # import xarray now fails
    with pytest.raises(ImportError, match=r'pip install "peeljax\[xarray\]"'):
        _map().to_xarray()
    with pytest.raises(ImportError, match=r'pip install "peeljax\[xarray\]"'):
        pj.sweep(V=1.1, tau=0.01, dt=0.01, t_final=0.1, out=tmp_path / "s.nc", progress=False)
    argv = ["sweep", "--V", "1.1", "--tau", "0.01", "--dt", "0.01", "--t-final", "0.1", "--out", str(tmp_path / "s.nc")]
    code, out, err = run_cli(argv)
    assert_refused(code, err, "--out", "s.nc", 'pip install "peeljax[xarray]"', stdout=out)
    assert list(tmp_path.iterdir()) == []
