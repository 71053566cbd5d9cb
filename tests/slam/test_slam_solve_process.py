"""The window solve in a child process (parallel mapping, issue 12): the same values as in place, through
marginalisation and a changing window, the tracker's interruption reaching it, its errors reaching the caller,
and a parallel run using it."""

from __future__ import annotations

import copy
import time

import pytest
import torch
from slam_scene import MemorySequence, preset_frames, small_config, synth_frames
from test_slam_window import _window

from codeslam.errors import CodeSLAMError
from codeslam.geometry.lie import se3_exp, se3_inverse
from codeslam.slam.config import SLAMConfig, overlay_config
from codeslam.slam.depth import standin_depth_model
from codeslam.slam.pipeline import run_slam
from codeslam.slam.solve_process import SolverProcess
from codeslam.slam.system import CodeSLAM

pytestmark = pytest.mark.skipif(not SolverProcess.supported(), reason="the solver process needs POSIX")


def _started(threads: int = 1) -> SolverProcess:
    sp = SolverProcess(threads)
    deadline = time.monotonic() + 120
    while not sp.ready:
        assert sp.alive and time.monotonic() < deadline, "the solver process did not start"
        time.sleep(0.02)
    return sp


def _same(a, b) -> None:
    for x, y in zip(a.keyframes, b.keyframes, strict=True):
        assert x.id == y.id and torch.equal(x.T_wc, y.T_wc) and torch.equal(x.code, y.code)
    assert a._pairs == b._pairs and a._affine.keys() == b._affine.keys()
    assert all(torch.equal(a._affine[k], b._affine[k]) for k in a._affine)


@pytest.fixture(scope="module")
def solver():
    sp = _started()
    yield sp
    sp.close()
    assert sp._proc.returncode == 0


def test_a_window_solved_in_the_process_ends_where_it_does_in_place(solver):
    """Four keyframes, then the oldest marginalised and a fifth added: the child keeps the views it was sent
    and is sent the new one; poses, codes, affine estimates, pairs, iterations and the marginal prior equal those
    computed in place (same torch threads, same operations)."""
    torch.set_num_threads(1)
    frames = synth_frames(3, 21, 10.0)[::5]  # keyframes 0, 5, 10, 15, 20
    G0 = se3_inverse(frames[0].pose)
    start = [G0 @ f.pose for f in frames]
    start = [start[0]] + [se3_exp(torch.tensor([0.01, 0.0, -0.01, 0.0, 0.01, 0.0], dtype=torch.float64)) @ T
                          for T in start[1:]]
    cfg = small_config(size=4)
    here = _window(frames[:4], cfg, start[:4])
    there = copy.deepcopy(here)
    before = solver.solves
    rep_here, rep_there = here.optimise(), solver.optimise(there)
    _same(here, there)
    assert rep_here.iterations == rep_there.iterations > 0 and rep_here.pairs == rep_there.pairs
    fifth = _window(frames, cfg, start).keyframes[4]
    here.remove_oldest()
    there.remove_oldest(solver.marginal_prior)  # the marginal prior computed there too
    assert here.prior is not None and here.prior.blocks == there.prior.blocks
    assert torch.equal(here.prior.H, there.prior.H) and torch.equal(here.prior.b, there.prior.b)
    assert all(torch.equal(a, b) for a, b in zip(here.prior.x0, there.prior.x0, strict=True))
    for w in (here, there):
        w.add(copy.deepcopy(fifth))
    rep_here, rep_there = here.optimise(), solver.optimise(there)
    _same(here, there)
    assert rep_here.iterations == rep_there.iterations > 0
    assert solver.solves == before + 3  # two solves and the marginalisation
    assert set(solver._sent) == {k.id for k in there.keyframes}  # the leaving keyframe's view is dropped


def test_the_trackers_interruption_reaches_the_solve_in_the_process(solver):
    """An interruption asked for before the first iteration ends the child's solve there (as in place), and the
    next solve is not cut short by it."""
    frames = synth_frames(3, 16, 10.0)[::5]
    G0 = se3_inverse(frames[0].pose)
    cfg = small_config(size=4, interrupt_finest_only=False)  # any level may be cut
    w = _window(frames, cfg, [G0 @ f.pose for f in frames])
    rep = solver.optimise(w, lambda: True)
    assert rep.interrupted and rep.iterations == 0
    rep = solver.optimise(w)
    assert not rep.interrupted and rep.iterations > 0


def test_an_error_in_the_solver_process_reaches_the_caller_in_one_line(solver):
    frames = synth_frames(3, 16, 10.0)[::5]
    G0 = se3_inverse(frames[0].pose)
    w = _window(frames, small_config(size=4), [G0 @ f.pose for f in frames])
    w.keyframes[1].code = torch.zeros(3)  # the wrong size: the solve cannot stack the codes
    with pytest.raises(CodeSLAMError, match="window solve in the solver process failed") as err:
        solver.optimise(w)
    assert "\n" not in str(err.value)
    w.keyframes[1].code = torch.zeros_like(w.keyframes[0].code)
    assert solver.optimise(w).iterations > 0  # the child goes on serving


def test_a_parallel_run_solves_its_windows_in_the_process_and_stops_it():
    """With ``window.solve_process`` the parallel mapper starts the child with the system; once it is ready the
    windows are solved there (the tracker is unchanged), and closing the run stops it."""
    seq = MemorySequence(preset_frames(21, 16, "walk", 10.0))
    system = CodeSLAM(overlay_config(SLAMConfig(), {"window": {"solve_process": True}}), standin_depth_model(),
                      parallel=True)
    sp = system.mapper._solver
    assert sp is not None
    deadline = time.monotonic() + 120
    while not sp.ready:
        assert sp.alive and time.monotonic() < deadline
        time.sleep(0.02)
    run = run_slam(seq, system, seq.frames[0].camera)
    assert all(r.tracking_ok for r in run.results)
    assert sp.solves >= system.mapper.updates >= 1  # every window solve (and marginalisation) there
    assert system.mapper._solver is None and sp._proc.returncode == 0  # closed by run_slam
    assert CodeSLAM(SLAMConfig(), standin_depth_model(), parallel=True).mapper._solver is None  # the default
    on = overlay_config(SLAMConfig(), {"window": {"solve_process": True}})
    assert CodeSLAM(on, standin_depth_model(), parallel=False).mapper._solver is None  # sequential: in place
