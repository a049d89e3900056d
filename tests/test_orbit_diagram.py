"""The orbit diagram's container, file, figure and command line, on a diagram made by hand
(nothing is integrated here: the continuation itself is tested in tests/test_orbits.py)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from matplotlib.figure import Figure

import peeljax as pj
from peeljax.cli import main
from peeljax.orbits import Bifurcation, BifurcationKind, OrbitBranch, OrbitDiagram, Seed
from peeljax.plots import plot_orbit_diagram


def _branch(V, k, stable, kinds) -> OrbitBranch:
    n = len(V)
    F_slip = 250 + 10 * (V - 1)
    return OrbitBranch(
        parameter="V", values=V, V=V, slips=np.full(n, k), period=np.full(n, 0.22),
        statistics={"F_mean": F_slip - 12, "F_slip": F_slip, "F_stick": F_slip - 25, "period": np.full(n, 0.22 / k),
                    "slip_duration": np.full(n, 2e-3)},
        multipliers=np.column_stack([np.where(stable, 0.5, 1.5), np.full(n, 0.01)]).astype(complex), stable=stable,
        test_functions={"fold": np.ones(n), "period_doubling": np.ones(n), "torus": np.linspace(-0.5, 0.5, n)},
        approach=np.linspace(-10, -1e-6, n), crossing=np.full(n, 3e3), section=np.column_stack([np.full(n, 0.3), 16 + V]),
        bifurcations=[Bifurcation(kind, float(V[j]), float(V[j]), k, j, "why") for kind, j in kinds],
        ends=["+V: grazing", "-V: left the bounds"], wall_time=1.5,
    )  # fmt: skip


@pytest.fixture
def diagram() -> OrbitDiagram:
    a = _branch(np.linspace(0.96, 1.10, 7), 8, np.arange(7) >= 2, [(BifurcationKind.TORUS, 2), (BifurcationKind.NEW_SLIP, 6)])
    b = _branch(np.linspace(1.05, 1.18, 5), 9, np.ones(5, bool), [(BifurcationKind.LOST_SLIP, 0)])
    seeds = [
        Seed(1.1, "paper", 8, 0.218, 259.6, 233.9, 0.0273, "converged", 0),
        Seed(1.1, "steady", 0, np.nan, 259.0, 233.0, 0.027, "no repeat", -1),
    ]
    return OrbitDiagram((0.9, 1.2), [a, b], seeds, 12.0, 3.0)


def test_diagram_file_round_trip(diagram, tmp_path):
    path = tmp_path / "branches.npz"
    diagram.save(path)
    loaded = pj.load(path)
    assert isinstance(loaded, OrbitDiagram)
    assert loaded.V_range == diagram.V_range and loaded.covered() == diagram.covered() == (1, 1)
    for mine, theirs in zip(diagram.branches, loaded.branches):
        for name in ("values", "V", "slips", "period", "multipliers", "stable", "approach", "crossing", "section"):
            np.testing.assert_array_equal(getattr(mine, name), getattr(theirs, name))
        for key in mine.statistics:
            np.testing.assert_array_equal(mine.statistics[key], theirs.statistics[key])
        assert [b.kind for b in mine.bifurcations] == [b.kind for b in theirs.bifurcations] and mine.ends == theirs.ends
    assert [s.orbit for s in loaded.seeds] == ["converged", "no repeat"]
    assert np.isnan(loaded.seeds[1].period)
    # A damaged file is refused, naming it.
    arrays = dict(np.load(path, allow_pickle=False))
    arrays["point_branch"] = arrays["point_branch"] + 5
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ValueError, match="bad.npz.*malformed"):
        pj.load(tmp_path / "bad.npz")


def test_diagram_figure_draws_into_own_or_users_axes(diagram, tmp_path):
    fig = plot_orbit_diagram(diagram, path=tmp_path / "d.png")
    assert (tmp_path / "d.png").stat().st_size > 0 and len(fig.axes) == 3
    mine = Figure()
    axes = mine.subplots(1, 3)
    assert plot_orbit_diagram(diagram, axes=axes) is mine
    assert len(axes[0].lines) > 4  # branches, bifurcation markers, seeds
    with pytest.raises(ValueError):
        plot_orbit_diagram(diagram, axes=axes[:2])


def test_diagram_summary_counts(diagram):
    text = str(diagram)
    assert "2 branches" in text and "1 periodic, 1 of them on a traced branch" in text
    assert [b.kind for _, b in diagram.bifurcations] == [BifurcationKind.TORUS, BifurcationKind.LOST_SLIP, BifurcationKind.NEW_SLIP]


@pytest.mark.parametrize(
    ("V", "message"),
    [
        ("1:2:3:4", "START:STOP"),
        ("2:1", "0 < START < STOP"),
        ("1:2:1", r"SEEDS must be an integer in \[2"),
        ("1:2:x", "SEEDS must be an integer"),
        ("-1:2", "--V"),
    ],
)
def test_the_diagram_command_refuses_bad_ranges_before_running(V, message, capsys):
    assert main(["orbit", f"--V={V}"]) == 2
    assert re.search(message, capsys.readouterr().err)


def test_the_diagram_command_refuses_slips():
    assert main(["orbit", "--V", "1:2", "--slips", "8"]) == 2


def test_an_interrupted_diagram_keeps_what_was_finished(diagram, tmp_path, monkeypatch, capsys):
    """Ctrl-C during ``peeljax orbit --V lo:hi:n --out``: the file holds the part finished (written
    as the diagram grows, marked incomplete), pj.load reads it, and the line on stderr says so."""
    import dataclasses

    def interrupted_after_one_branch(*args, on_progress=None, **kwargs):
        if on_progress is not None:  # (the command passes one only with --out)
            on_progress(dataclasses.replace(diagram, branches=diagram.branches[:1], complete=False))
        raise KeyboardInterrupt

    monkeypatch.setattr("peeljax.orbits.orbit_diagram", interrupted_after_one_branch)
    out = tmp_path / "branches.npz"
    assert main(["orbit", "--V", "0.9:1.2:3", "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert "marked incomplete" in err and "1 branch" in err and "pj.load" in err, err
    kept = pj.load(out)
    assert not kept.complete and len(kept.branches) == 1 and "incomplete" in str(kept)
    np.testing.assert_array_equal(kept.branches[0].V, diagram.branches[0].V)
    # without --out nothing is kept, and the line says so
    assert main(["orbit", "--V", "0.9:1.2:3"]) == 130
    assert "nothing was saved" in capsys.readouterr().err
    # a finished diagram's file is complete
    diagram.save(out)
    assert pj.load(out).complete


@pytest.mark.slow
def test_orbit_diagram_reports_what_it_finished_as_it_goes():
    """A small real diagram: ``on_progress`` gets the part finished after each seed's V and each
    branch (incomplete, growing), and the diagram returned is complete and holds them all."""
    parts = []
    diagram = pj.orbit_diagram(V=(1.05, 1.1), seeds=2, starts=("paper",), t_final=3.0, progress=False,
                               on_progress=parts.append)  # fmt: skip
    assert diagram.complete and not any(part.complete for part in parts)
    assert [len(part.seeds) for part in parts[:2]] == [1, 2]
    assert len(parts) == 2 + len(diagram.branches) and len(diagram.branches) >= 1
    assert [len(part.branches) for part in parts[2:]] == list(range(1, len(diagram.branches) + 1))
    assert [s.branch for s in parts[-1].seeds] == [s.branch for s in diagram.seeds]


@pytest.mark.slow
def test_the_diagram_command_numbers_branches_alike_on_both_streams(capsys):
    """`peeljax orbit --V lo:hi:n`: the progress on stderr and the summary on stdout name each
    branch by the same number (its index in diagram.branches)."""
    assert main(["orbit", "--V", "1.05:1.1:2"]) == 0
    captured = capsys.readouterr()
    progress = re.findall(r"branch (\d+): (\d+) slips per period", captured.err)
    summary = re.findall(r"branch (\d+): (\d+) slips per period", captured.out)
    assert progress and [b for b, _ in progress] == [str(i) for i in range(len(progress))]
    assert dict(progress) == {b: k for b, k in summary}
