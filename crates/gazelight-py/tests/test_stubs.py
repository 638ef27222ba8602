"""The type stubs name what the native module has: every public class,
function and method in one is in the other, with the same parameters for
the functions and constructors."""

import ast
import inspect
from pathlib import Path

import gazelight
from gazelight import _gazelight

STUB = Path(gazelight.__file__).with_name("_gazelight.pyi")


def _stub():
    tree = ast.parse(STUB.read_text())
    out = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            out[node.name] = {n.name: n for n in node.body if isinstance(n, ast.FunctionDef)}
            out[node.name].update(
                {n.target.id: n for n in node.body if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)}
            )
        elif isinstance(node, ast.FunctionDef):
            out[node.name] = node
    return out


def _params(fn):
    return [a.arg for a in fn.args.args + fn.args.kwonlyargs if a.arg not in ("self",)]


def test_stubs_match_the_native_module():
    stub = _stub()
    native = {n for n in dir(_gazelight) if not n.startswith("_")}
    assert set(stub) == native, (set(stub) ^ native)
    for name, entry in stub.items():
        obj = getattr(_gazelight, name)
        if isinstance(entry, dict):
            public = {m for m in dir(obj) if not m.startswith("_")} - set(dir(Exception))
            stubbed = {m for m in entry if not m.startswith("_")}
            assert stubbed == public, (name, stubbed ^ public)
            if "__init__" in entry and obj.__text_signature__:
                sig = [p for p in inspect.signature(obj).parameters if p not in ("self", "args", "kwargs")]
                assert _params(entry["__init__"]) == sig, name
        else:
            assert _params(entry) == list(inspect.signature(obj).parameters), name
