"""The runtime boundary: numpy, onnxruntime, tokenizers and pillow only; no pickle."""
import ast
import pkgutil
import sys
from pathlib import Path

import mogo.runtime

RUNTIME_DIR = Path(mogo.runtime.__file__).parent
ALLOWED_THIRD_PARTY = {"numpy", "onnxruntime", "tokenizers", "PIL"}


def runtime_sources():
    return sorted(RUNTIME_DIR.rglob("*.py"))


def test_runtime_imports_only_allowed_packages():
    stdlib = set(sys.stdlib_module_names)
    for path in runtime_sources():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                assert top in stdlib or top in ALLOWED_THIRD_PARTY or name.startswith(
                    "mogo.runtime"), f"{path.name} imports {name}"


def test_runtime_loads_no_pickle():
    for path in runtime_sources():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [a.name for a in node.names] + [getattr(node, "module", None) or ""]
                assert not any(n.split(".")[0] in ("pickle", "dill", "joblib") for n in names)
            if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "load":
                keywords = {k.arg: k.value for k in node.keywords}
                if "allow_pickle" in keywords or getattr(node.func.value, "id", "") == "np":
                    value = keywords.get("allow_pickle")
                    assert isinstance(value, ast.Constant) and value.value is False, (
                        f"{path.name}:{node.lineno} np.load without allow_pickle=False")


def test_runtime_imports_with_torch_unimportable(run_without_torch):
    modules = [f"mogo.runtime.{m.name}" for m in pkgutil.iter_modules([str(RUNTIME_DIR)])]
    result = run_without_torch(f"import importlib\nfor m in {modules!r}:\n"
                               "    importlib.import_module(m)\nprint('ok', len(sys.modules))\n")
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("ok")
