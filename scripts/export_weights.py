"""Export the network of a training run (its final weights, or its latest checkpoint while it is still
running or was interrupted) as a standalone weights file with provenance in its metadata.

    python scripts/export_weights.py runs/default codeslam/weights/codeslam_default.safetensors

The file holds only the model tensors and its config (no optimiser state), so it is what every command
loads. The metadata records the run's step and its total steps, so an interim export is never mistaken for
a finished run.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from safetensors import safe_open

from codeslam.errors import CodeSLAMError
from codeslam.network.weights import load_model, save_weights


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run", type=Path, help="training run folder (weights.safetensors or checkpoint.safetensors)")
    p.add_argument("out", type=Path, help="weights file to write")
    args = p.parse_args()
    final = args.run / "weights.safetensors"
    src = final if final.is_file() else args.run / "checkpoint.safetensors"
    try:
        model = load_model(src)
        with safe_open(str(src), framework="pt") as f:
            meta = dict(f.metadata() or {})
    except CodeSLAMError as e:
        print(f"export_weights: error: {e}", file=sys.stderr)
        return 2
    extra = {"source": "final weights" if src == final else "checkpoint (interim)", "run": str(args.run)}
    for key in ("step", "train_config", "extra"):
        if key in meta:
            extra[key] = meta[key]
    save_weights(args.out, model, extra_metadata=extra)
    print(f"wrote {args.out} from {src} ({', '.join(f'{k}={v}' for k, v in extra.items() if k in ('source', 'step'))})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
