"""``codeslam info DATASET``: what a dataset folder holds, read the way every other command reads it."""

from __future__ import annotations

from codeslam.cli.app import app
from codeslam.cli.common import DatasetArg, Format, JsonOut


@app.command()
def info(
    dataset: DatasetArg,
    fmt: Format = None,
    json_path: JsonOut = None,
) -> None:
    """Show the frames, camera, depth and ground truth of a dataset (reads the first frame to check it)."""
    from rich.console import Console
    from rich.table import Table

    from codeslam.cli.common import reader_warnings
    from codeslam.data.registry import describe_dataset, open_dataset
    from codeslam.io import write_json

    with reader_warnings():  # the first frame is read too
        summary = describe_dataset(open_dataset(dataset, format=fmt))
    table = Table(title=f"{summary['path']} ({summary['format']})", show_header=False)
    table.add_column("key", style="bold")
    table.add_column("value")
    first = summary["first_frame"]
    rows = [
        ("frames", str(summary["frames"])),
        ("image size", f"{summary['width']} x {summary['height']}"),
        ("fx fy cx cy", " ".join(f"{summary[k]:.3f}" for k in ("fx", "fy", "cx", "cy"))),
        ("distortion", " ".join(f"{v:g}" for v in summary["distortion"])
         + (" (undistorted)" if summary["undistorted"] else "")),
        ("duration", f"{summary['duration_s']:.3f} s"),
        ("depth", "yes" if summary["has_depth"] else "no"),
        ("ground truth", f"{summary['frames_with_pose']} of {summary['frames']} frames"
         if summary["has_pose"] else "no"),
    ]
    if summary["gt_path_length_m"] is not None:
        rows.append(("gt path length", f"{summary['gt_path_length_m']:.3f} m"))
    if first.get("depth_min_m") is not None:
        rows.append(("first frame depth",
                     f"{first['depth_min_m']:.3f} - {first['depth_max_m']:.3f} m, "
                     f"{100 * first['depth_valid_fraction']:.1f}% valid"))
    for k, v in rows:
        table.add_row(k, v)
    Console().print(table)
    if json_path is not None:
        write_json(json_path, summary)
