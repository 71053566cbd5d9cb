"""Static check of the package source (issue 6, item 2): nothing that can execute a data file is used.

Parsed with :mod:`ast` rather than grepped, so that ``model.eval()`` (a method) is not taken for the built-in
``eval(...)`` and a word in a docstring is not taken for a call. Forbidden:

* importing ``pickle`` / ``cPickle`` / ``dill`` / ``cloudpickle`` / ``joblib`` / ``marshal`` / ``shelve``;
* ``torch.load`` (unpickles), ``numpy.load`` without ``allow_pickle=False``, ``torch.jit.load``;
* ``yaml.load`` / ``yaml.load_all`` without ``Loader=yaml.SafeLoader``, ``yaml.unsafe_load``, ``yaml.full_load``,
  ``yaml.Loader`` / ``UnsafeLoader`` / ``FullLoader``;
* the built-ins ``eval``, ``exec``, ``compile``, ``__import__`` and ``os.system`` / ``subprocess`` with
  ``shell=True``.

:data:`ALLOWED` lists exceptions as (file, name) with the reason: one, a process talking to its own child.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "codeslam"

UNSAFE_MODULES = {"pickle", "cPickle", "_pickle", "dill", "cloudpickle", "joblib", "marshal", "shelve"}
UNSAFE_BUILTINS = {"eval", "exec", "compile", "__import__"}
UNSAFE_YAML = {"unsafe_load", "unsafe_load_all", "full_load", "full_load_all", "Loader", "UnsafeLoader",
               "FullLoader"}
#: (path relative to the package, name) -> why it is safe
ALLOWED: dict[tuple[str, str], str] = {
    # The parallel mapper's window solver (window.solve_process) and its child interpreter exchange pickled
    # windows over two anonymous pipes that the parent creates and hands to the child alone (subprocess
    # pass_fds): no file, socket or path that anything else could write to, and nothing read from disk.
    ("slam/solve_process.py", "import pickle"): "in-memory exchange with the process's own child over private pipes",
}


def _dotted(node: ast.AST) -> str:
    """``a.b.c`` of a Name / Attribute chain, '' for anything else."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        parts.append(node.id)
        return ".".join(reversed(parts))
    return ""


def _kw(call: ast.Call, name: str) -> ast.AST | None:
    return next((k.value for k in call.keywords if k.arg == name), None)


def unsafe_uses(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, what) of every forbidden construct in a module's syntax tree."""
    found = []
    aliases = {}  # local name -> module it stands for ("np" -> "numpy")
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                aliases[a.asname or a.name.split(".")[0]] = a.name if a.asname else a.name.split(".")[0]
                if a.name.split(".")[0] in UNSAFE_MODULES:
                    found.append((node.lineno, f"import {a.name}"))
        elif isinstance(node, ast.ImportFrom):
            mod = (node.module or "").split(".")[0]
            for a in node.names:
                if mod in UNSAFE_MODULES or (mod == "yaml" and a.name in UNSAFE_YAML | {"load", "load_all"}):
                    found.append((node.lineno, f"from {node.module} import {a.name}"))
                if mod in ("torch", "numpy") and a.name == "load":
                    found.append((node.lineno, f"from {node.module} import load"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            name = _dotted(node)
            head, _, rest = name.partition(".")
            full = f"{aliases.get(head, head)}.{rest}" if rest else name
            if full.startswith("yaml.") and full.split(".", 1)[1] in UNSAFE_YAML:
                found.append((node.lineno, full))
        if not isinstance(node, ast.Call):
            continue
        name = _dotted(node.func)
        head, _, rest = name.partition(".")
        full = f"{aliases.get(head, head)}.{rest}" if rest else name
        if name in UNSAFE_BUILTINS:
            found.append((node.lineno, f"{name}()"))
        elif full in ("torch.load", "torch.jit.load", "torch.serialization.load"):
            found.append((node.lineno, f"{full}()"))
        elif full == "numpy.load":
            allow = _kw(node, "allow_pickle")
            if not (isinstance(allow, ast.Constant) and allow.value is False):
                found.append((node.lineno, "numpy.load() without allow_pickle=False"))
        elif full in ("yaml.load", "yaml.load_all"):
            loader = _kw(node, "Loader") or (node.args[1] if len(node.args) > 1 else None)
            if _dotted(loader) not in ("yaml.SafeLoader", "yaml.CSafeLoader", "SafeLoader", "CSafeLoader"):
                found.append((node.lineno, f"{full}() without Loader=yaml.SafeLoader"))
        elif full == "os.system" or full.startswith("os.popen"):
            found.append((node.lineno, f"{full}()"))
        elif full.startswith("subprocess."):
            shell = _kw(node, "shell")
            if not (shell is None or (isinstance(shell, ast.Constant) and shell.value is False)):
                found.append((node.lineno, f"{full}(shell=...)"))
    return found


SOURCES = sorted(PACKAGE.rglob("*.py"))


def test_the_package_is_there():
    assert len(SOURCES) > 30 and (PACKAGE / "network" / "weights.py") in SOURCES


@pytest.mark.parametrize("path", SOURCES, ids=[str(p.relative_to(PACKAGE)) for p in SOURCES])
def test_no_unsafe_deserialisation_or_code_execution(path):
    rel = str(path.relative_to(PACKAGE))
    uses = [(line, what) for line, what in unsafe_uses(ast.parse(path.read_text(), str(path)))
            if (rel, what) not in ALLOWED]
    assert not uses, f"{rel}: " + "; ".join(f"line {line}: {what}" for line, what in uses)


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("import pickle\npickle.loads(b'')", "import pickle"),
        ("from pickle import loads", "from pickle import loads"),
        ("import torch\ntorch.load('w.pt')", "torch.load()"),
        ("import torch as T\nT.load('w.pt', weights_only=True)", "torch.load()"),
        ("import numpy as np\nnp.load('d.npy')", "numpy.load() without allow_pickle=False"),
        ("import numpy as np\nnp.load('d.npy', allow_pickle=True)", "numpy.load() without allow_pickle=False"),
        ("import yaml\nyaml.load(s)", "yaml.load() without Loader=yaml.SafeLoader"),
        ("import yaml\nyaml.load(s, Loader=yaml.FullLoader)", "yaml.FullLoader"),
        ("import yaml\nyaml.unsafe_load(s)", "yaml.unsafe_load"),
        ("eval(text)", "eval()"),
        ("exec(text)", "exec()"),
        ("import os\nos.system(cmd)", "os.system()"),
        ("import subprocess\nsubprocess.run(cmd, shell=True)", "subprocess.run(shell=...)"),
    ],
)
def test_the_check_catches_each_construct(source, expected):
    assert expected in [what for _, what in unsafe_uses(ast.parse(source))]


@pytest.mark.parametrize(
    "source",
    [
        "model.eval()",
        "import yaml\nyaml.safe_load(s)",
        "import yaml\nyaml.load(s, Loader=yaml.SafeLoader)",
        "import numpy as np\nnp.load(p, allow_pickle=False)",
        "from safetensors.torch import load_file\nload_file(p)",
        "import subprocess\nsubprocess.run(['ls'])",
        "'''pickle, torch.load and eval( in a docstring'''",
    ],
)
def test_the_check_passes_safe_code(source):
    assert unsafe_uses(ast.parse(source)) == []
