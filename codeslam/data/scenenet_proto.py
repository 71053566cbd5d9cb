"""The SceneNet RGB-D trajectory protobuf, built at run time (no ``protoc`` and no generated code needed).

The dataset's ``scenenet.proto`` (McCormac et al., pySceneNetRGBD) defines, among others::

    message Position     { optional float x = 1; optional float y = 2; optional float z = 3; }
    message Pose         { optional Position camera = 1; optional Position lookat = 2;
                           optional float timestamp = 3; }
    message View         { optional int32 frame_num = 1; optional Pose shutter_open = 2;
                           optional Pose shutter_close = 3; }
    message Trajectory   { optional SceneLayout layout = 1; repeated Instance instances = 2;
                           repeated View views = 3; optional string render_path = 4; }
    message Trajectories { repeated Trajectory trajectories = 1; }

Only the fields the reader uses are declared here; ``layout`` and ``instances`` (fields 1 and 2 of
Trajectory) are skipped by the parser as unknown fields. The wire types must match the dataset's file
exactly (``float``, i.e. fixed32, for coordinates and timestamps). The classes live in a private
descriptor pool so they never clash with a user's own compiled ``scenenet_pb2``.

protobuf is an optional dependency (``pip install codeslam[scenenet]``), imported only when a SceneNet
protobuf is read.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

from codeslam.errors import DatasetError

_PACKAGE = "codeslam_scenenet"


def _import_protobuf():
    try:
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
        from google.protobuf.message import DecodeError
    except ImportError:
        raise DatasetError(
            "reading SceneNet RGB-D needs the 'protobuf' package: pip install 'codeslam[scenenet]'"
        ) from None
    return descriptor_pb2, descriptor_pool, message_factory, DecodeError


@functools.lru_cache(maxsize=1)
def message_classes() -> dict[str, Any]:
    """The message classes ``{"Position", "Pose", "View", "Trajectory", "Trajectories"}``."""
    descriptor_pb2, descriptor_pool, message_factory, _ = _import_protobuf()
    F = descriptor_pb2.FieldDescriptorProto
    fdp = descriptor_pb2.FileDescriptorProto(name="codeslam_scenenet.proto", package=_PACKAGE, syntax="proto2")

    def message(name: str, fields: list[tuple[str, int, int, int, str]]) -> None:
        m = fdp.message_type.add(name=name)
        for fname, number, ftype, label, type_name in fields:
            f = m.field.add(name=fname, number=number, type=ftype, label=label)
            if type_name:
                f.type_name = f".{_PACKAGE}.{type_name}"

    opt, rep = F.LABEL_OPTIONAL, F.LABEL_REPEATED
    msg, flt = F.TYPE_MESSAGE, F.TYPE_FLOAT
    message("Position", [("x", 1, flt, opt, ""), ("y", 2, flt, opt, ""), ("z", 3, flt, opt, "")])
    message("Pose", [("camera", 1, msg, opt, "Position"), ("lookat", 2, msg, opt, "Position"),
                     ("timestamp", 3, flt, opt, "")])
    message("View", [("frame_num", 1, F.TYPE_INT32, opt, ""), ("shutter_open", 2, msg, opt, "Pose"),
                     ("shutter_close", 3, msg, opt, "Pose")])
    message("Trajectory", [("views", 3, msg, rep, "View"), ("render_path", 4, F.TYPE_STRING, opt, "")])
    message("Trajectories", [("trajectories", 1, msg, rep, "Trajectory")])

    pool = descriptor_pool.DescriptorPool()
    pool.AddSerializedFile(fdp.SerializeToString())
    names = ("Position", "Pose", "View", "Trajectory", "Trajectories")
    return {n: message_factory.GetMessageClass(pool.FindMessageTypeByName(f"{_PACKAGE}.{n}")) for n in names}


def read_trajectories(path: str | Path) -> Any:
    """Parse a SceneNet ``*.pb`` file -> a ``Trajectories`` message; DatasetError when it is not one."""
    path = Path(path)
    _, _, _, DecodeError = _import_protobuf()
    cls = message_classes()["Trajectories"]
    try:
        data = path.read_bytes()
    except OSError as e:
        raise DatasetError(f"cannot read {path}: {e}") from None
    msg = cls()
    try:
        msg.ParseFromString(data)
    except (DecodeError, ValueError, RuntimeError) as e:
        raise DatasetError(f"{path} is not a SceneNet trajectories protobuf: {e}") from None
    return msg
