"""Which terms of a window solve hold the map's scale? (issue 11, ``window.free_scale``)

Runs ``codeslam slam`` in this process and, after each window solve named by ``--solves``, reads every term of the
window's cost at the solved state, at one pyramid level: its derivative along the direction that scales the window
(every keyframe's depth by exp(1) through its scale entry and every keyframe's position away from the oldest
keyframe's by the same factor, to first order) and its curvature ``d^T H d`` there. The data terms (photometric,
geometric, keypoints) are exactly scale-free, so they read 0; what is left says which priors hold the window's
scale and how firmly. A positive derivative pulls the window smaller, a negative one larger. Needs the window's
scale entry (``--config`` with ``window: {free_scale: true, map_prior_weight: 0, sfm: {geometric_pose_min_std: 0}}``):
with the code alone no code direction is a pure scale.

Measured (docs/results/slam_table.md, twenty-fifth session; generator walk 43, solves 30-34): photometric,
geometric, keypoints 0.00; the marginal prior +21 to +42 (curvature 1.5-2.2e5); the four depth scale priors -33 to
-38 (curvature 44); the code prior on the scales -1.1 to -1.8.

    python scripts/window_scale_terms.py --solves 30 34 [--level 0] -- DATA --config F.yaml [slam options]
"""

from __future__ import annotations

import argparse
import copy
import sys
from dataclasses import replace

import torch

#: The window's terms by class, as the table names them.
LABELS = {"LinearPrior": "marginal prior", "StackedReprojectionTerm": "keypoints", "VelocityPrior": "velocity prior",
          "DepthScalePrior": "depth scale priors", "WindowScalePrior": "window scale prior"}


def scale_terms(window, level: int = 0) -> dict[str, tuple[float, float]]:
    """Each cost term of ``window`` (a :class:`~codeslam.slam.window.SlidingWindow` whose keyframes have a scale
    entry) at its current state: name -> (derivative, curvature) along the window's scale direction (module
    docstring), from the term's own gradient and Gauss-Newton Hessian."""
    from codeslam.sfm.keyframes import build_levels
    from codeslam.sfm.normal_equations import assemble
    from codeslam.sfm.priors import CodePrior
    from codeslam.sfm.residuals import evaluate_pairs, pair_jacobians
    from codeslam.sfm.variables import CODE, POSE, BlockId

    if not all(k.free_scale for k in window.keyframes):
        raise SystemExit("window_scale_terms: the window's keyframes have no scale entry (window.free_scale)")
    cfg = window.cfg.sfm
    dtype, device = window._tensors()
    _, pairs, state, layout = window.problem()
    F_ = state.codes.shape[0]
    lvl = build_levels([k.view for k in window.keyframes], [level], dtype, device)[level]
    d = torch.zeros(layout.dim, dtype=torch.float64)
    origin = state.poses[0, :3, 3]
    for i in range(F_):
        sl = layout.slice(BlockId(POSE, i))
        if sl is not None:  # a left increment's translation part moves the position in the world frame
            d[sl.start:sl.start + 3] = (state.poses[i, :3, 3] - origin).double()
        d[layout.slice(BlockId(CODE, i)).stop - 1] = 1.0

    def along(H: torch.Tensor, g: torch.Tensor) -> tuple[float, float]:
        return float(g.double().cpu() @ d), float(d @ H.double().cpu() @ d)

    def data(types: dict) -> tuple[torch.Tensor, torch.Tensor]:
        c = replace(cfg, **types)
        ev = evaluate_pairs(lvl, pairs, state.poses, state.codes, state.affine if c.affine_brightness else None, c)
        lvl.refresh_scale_column(state.codes)
        return assemble(pair_jacobians(lvl, pairs, ev), pairs, state.poses, lvl, layout)

    def alone(term) -> tuple[float, float]:
        H = torch.zeros(layout.dim, layout.dim, dtype=dtype, device=device)
        g = torch.zeros(layout.dim, dtype=dtype, device=device)
        term.add_to(H, g, layout, state)
        return along(H, g)

    out = {"photometric": along(*data({"geometric": False})), "geometric": along(*data({"photometric": False}))}
    for term in window.level_terms(lvl, window.sparse_terms()):  # the solve's own terms, at the prior's full weight
        out[LABELS.get(type(term).__name__, type(term).__name__)] = alone(term)
    out["code prior"] = alone(CodePrior(cfg.code_prior_weight))
    return out


def main() -> None:
    argv = sys.argv[1:]
    ours, slam = (argv[:argv.index("--")], argv[argv.index("--") + 1:]) if "--" in argv else (argv, [])
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--solves", type=int, nargs="+", required=True, help="window solves to read (1 = the first)")
    ap.add_argument("--level", type=int, default=0, help="pyramid level of the data terms")
    args = ap.parse_args(ours)
    if not slam:
        ap.error("give the slam command's arguments after --: DATA [options]")

    import codeslam.slam.window as window_module
    from codeslam.cli import main as cli

    solve = window_module.SlidingWindow.optimise
    count, rows = [0], []

    def optimise(self, *a, **k):
        report = solve(self, *a, **k)
        count[0] += 1
        if count[0] in args.solves:
            terms = scale_terms(copy.deepcopy(self), args.level)
            rows.append((count[0], [k.id for k in self.keyframes], [float(k.code[-1]) for k in self.keyframes],
                         terms))
        return report

    window_module.SlidingWindow.optimise = optimise
    rc = cli(["slam", *slam, "-q"])
    if rc:
        raise SystemExit(rc)
    names = list(dict.fromkeys(n for *_, t in rows for n in t))
    print("| solve (keyframes) | scales | " + " | ".join(names) + " |")
    print("|---" * (len(names) + 2) + "|")
    for n, ids, scales, terms in rows:
        cells = [f"{terms[x][0]:+.2f} ({terms[x][1]:.3g})" if x in terms else "" for x in names]
        print(f"| {n} ({ids[0]}-{ids[-1]}) | {' '.join(f'{s:+.2f}' for s in scales)} | " + " | ".join(cells) + " |")
    print("\nEach cell: the derivative along the window's scale (+: towards a smaller map) and the curvature.")


if __name__ == "__main__":
    main()
