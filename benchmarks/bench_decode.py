"""A keyframe's decoding (issue 12: "decode plus code Jacobian at most 200 ms per keyframe"), with the code Jacobian
in each type that ``jacobian_dtype`` offers, measured in turn in one run, and the ratio to float32.

What SLAM does once per keyframe (:func:`codeslam.slam.depth.network_depth_model`): the image features, the
zero-code proximity, the code Jacobian on every level and the uncertainty, with the shipped weights at the network's
128x96. The image is a smooth random one (the time does not depend on the content); with ``--image`` a real one.
Also printed: the largest error of the Jacobian against float32's, relative to its largest entry.

    python benchmarks/bench_decode.py [--threads 2] [--repeats 9] [--weights W] [--image PATH]

Nothing in the test suite asserts on time.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import torch


def main() -> None:
    from codeslam.errors import CodeSLAMError

    try:
        _bench()
    except CodeSLAMError as e:  # a missing or bad weights file or image: one line, no traceback
        print(f"bench_decode: {e}", file=sys.stderr)
        sys.exit(1)


def _bench() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=9, help="timed decodings of each type, alternating")
    ap.add_argument("--weights", default=None, help="network weights (default: the shipped ones)")
    ap.add_argument("--image", default=None, help="an RGB image to decode (default: a smooth random one)")
    args = ap.parse_args()
    if args.threads < 1 or args.repeats < 1:
        ap.error("--threads and --repeats must be at least 1")
    from codeslam.cli.common import keep_freed_memory

    # As the codeslam command does at its start: without it every decoding faults its tens of MB of fresh pages in
    # again (measured, 1 thread, Zen 3, two fresh processes each: 294-304 against 226-241 ms), which SLAM never pays.
    keep_freed_memory()
    torch.set_num_threads(args.threads)

    from codeslam.data.imageio import read_rgb
    from codeslam.depthmodel import DepthModel
    from codeslam.network.jacobian import jacobian_dtype

    model = DepthModel.load(args.weights)
    cam = model.camera
    if args.image:
        image = torch.nn.functional.interpolate(read_rgb(args.image)[None], size=(cam.height, cam.width),
                                                mode="bilinear", antialias=True, align_corners=False)[0]
    else:
        gen = torch.Generator().manual_seed(0)
        coarse = torch.rand(1, 3, cam.height // 8, cam.width // 8, generator=gen)
        image = torch.nn.functional.interpolate(coarse, size=(cam.height, cam.width), mode="bicubic")[0]
    image = image.clamp(0, 1)
    auto = jacobian_dtype("auto")
    dtypes = {"float32": torch.float32, "bfloat16": torch.bfloat16}

    def decode(dtype: torch.dtype):
        return model.linear_decoders(model.features(image[None]), jacobian_dtype=dtype)[0]

    ref = {name: decode(dt) for name, dt in dtypes.items()}  # warm-up, and the Jacobians compared
    times: dict[str, list[float]] = {name: [] for name in dtypes}
    for _ in range(args.repeats):
        for name, dt in dtypes.items():
            t0 = time.perf_counter()
            decode(dt)
            times[name].append(1e3 * (time.perf_counter() - t0))
    base = float(np.median(times["float32"]))
    print(f"keyframe decoding at {cam.width}x{cam.height}, code {model.code_size}, {args.threads} threads, "
          f"{args.repeats} runs each, alternating; 'auto' here is {str(auto).removeprefix('torch.')}")
    J32 = ref["float32"].levels[0].jac
    for name, ts in times.items():
        med, p90 = float(np.median(ts)), float(np.percentile(ts, 90))  # as bench_slam.py reports its stages
        err = float((ref[name].levels[0].jac - J32).abs().max() / J32.abs().max())
        print(f"  {name:9s} median {med:7.1f} ms  p90 {p90:7.1f} ms  ratio to float32 {med / base:.3f}  "
              f"largest Jacobian error {err:.1e} of its largest entry")


if __name__ == "__main__":
    main()
