"""The layout's contract: which folder may import which, the runtime on numpy + onnxruntime +
tokenizers + pillow only, no pickle, and the runtime working with torch unimportable."""

import ast
import sys
from pathlib import Path

import pytest

import mogo

RUNTIME_DIR = Path(mogo.__file__).parent
ROOT = RUNTIME_DIR.parent
ALLOWED_THIRD_PARTY = {"numpy", "onnxruntime", "tokenizers", "PIL"}
# runtime/serve/ only: `pip install 'mogo-edge[serve]'`
SERVE_EXTRA = {"aiohttp", "onnx", "threadpoolctl"}

# Each room (a package, with the packages under it) -> the mogo modules its files may import,
# lazily or not, and the exceptions to that. No room imports one above it: runtime < export <
# bench, and within runtime, motion maths below the engine; the quality bench needs no torch.
LATER = ("mogo.export", "mogo.bench")
MAY_IMPORT = {
    "mogo.motion": (("mogo.motion",), ()),
    "mogo": (("mogo",), LATER + ("mogo.serve",)),  # nothing of the runtime needs the server
    "mogo.serve": (("mogo",), LATER),
    "mogo.export": (("mogo",), ("mogo.bench",)),
    # within export: data (numpy) < models (torch, and runs read back) < onnx < train < cli
    "mogo.export.data": (
        ("mogo",),
        (
            "mogo.bench",
            "mogo.export.models",
            "mogo.export.onnx",
            "mogo.export.train",
            "mogo.export.cli",
        ),
    ),
    "mogo.export.models": (
        ("mogo",),
        ("mogo.bench", "mogo.export.onnx", "mogo.export.train", "mogo.export.cli"),
    ),
    "mogo.export.onnx": (("mogo",), ("mogo.bench", "mogo.export.train", "mogo.export.cli")),
    "mogo.export.train": (("mogo",), ("mogo.bench", "mogo.export.cli")),
    "mogo.bench": (("mogo",), ()),
    "mogo.bench.quality": (
        ("mogo",),
        (
            "mogo.export.models",
            "mogo.export.train",
            "mogo.export.onnx",
            "mogo.bench.speed",
            "mogo.bench.training",
        ),
    ),
}


ADDON_DIR = RUNTIME_DIR / "blender" / "addon"  # package data run by Blender, not a room of mogo
# The add-on's imports: Blender's modules, numpy, and of mogo its public API and the motion
# maths (the rig solves the rotations), no second implementation of either.
ADDON_MAY_IMPORT = {
    "bpy",
    "mathutils",
    "addon_utils",
    "numpy",
    "mogo",
    "mogo.motion.rig",
    "mogo.motion.bvh",
    "mogo.motion.quaternion",
}


CODE_FOLDERS = ("runtime", "export", "bench", "tests")  # the repository's code (no venvs)


def sources(folder: Path):
    return sorted(
        p
        for p in folder.rglob("*.py")
        if ".venv" not in p.parts and not p.is_relative_to(ADDON_DIR)
    )


def package_of(path: Path) -> str:
    """runtime/motion/bvh.py -> mogo.motion; export/data/corpus.py -> mogo.export.data."""
    folder = path.parent.relative_to(ROOT).parts
    return ".".join(["mogo" if folder[0] == "runtime" else f"mogo.{folder[0]}", *folder[1:]])


def imported_modules(path: Path) -> list[str]:
    """Absolute module names imported anywhere in the file, function bodies included."""
    names = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the file's package
                parts = package_of(path).split(".")
                base = parts[: len(parts) - node.level + 1]
                names.append(".".join(base + ([node.module] if node.module else [])))
            else:
                names.append(node.module)
    return names


def within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def rules_for(package: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    return MAY_IMPORT[max((room for room in MAY_IMPORT if within(package, room)), key=len)]


@pytest.mark.parametrize("folder", ["runtime", "export", "bench"])
def test_no_room_imports_one_above_it(folder):
    for path in sources(ROOT / folder):
        package = package_of(path)
        allowed, denied = rules_for(package)
        for name in filter(lambda name: within(name, "mogo"), imported_modules(path)):
            assert any(within(name, p) for p in allowed) and not any(
                within(name, p) for p in denied
            ), f"{path.relative_to(ROOT)} ({package}) imports {name}"


def test_runtime_imports_only_allowed_packages():
    stdlib = set(sys.stdlib_module_names)
    for path in sources(RUNTIME_DIR):
        extra = SERVE_EXTRA if package_of(path) == "mogo.serve" else set()
        for name in imported_modules(path):
            top = name.split(".")[0]
            assert top in stdlib or top in ALLOWED_THIRD_PARTY | extra or top == "mogo", (
                f"{path.name} imports {name}"
            )


def test_the_blender_addon_uses_the_public_api_and_is_not_imported_by_the_runtime():
    stdlib = set(sys.stdlib_module_names)
    for path in sorted(ADDON_DIR.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.level:
                continue  # the add-on's own modules
            if isinstance(node, ast.Import):
                names = [[a.name] for a in node.names]
            elif isinstance(node, ast.ImportFrom):  # from mogo.motion import rig: either name
                names = [[node.module] + [f"{node.module}.{a.name}" for a in node.names]]
            else:
                continue
            for forms in names:
                assert forms[0].split(".")[0] in stdlib or ADDON_MAY_IMPORT & set(forms), (
                    f"{path.name} imports {forms[-1]}"
                )
    for path in (p for folder in CODE_FOLDERS for p in sources(ROOT / folder)):
        assert not any(within(n, "mogo.blender.addon") for n in imported_modules(path)), path


def test_runtime_loads_no_pickle():
    for path in sources(RUNTIME_DIR):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [a.name for a in node.names] + [getattr(node, "module", None) or ""]
                assert not any(n.split(".")[0] in ("pickle", "dill", "joblib") for n in names)
            if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "load":
                keywords = {k.arg: k.value for k in node.keywords}
                if "allow_pickle" in keywords or getattr(node.func.value, "id", "") == "np":
                    value = keywords.get("allow_pickle")
                    assert isinstance(value, ast.Constant) and value.value is False, (
                        f"{path.name}:{node.lineno} np.load without allow_pickle=False"
                    )


def import_every_module_without_torch(run_without_torch, folders: list[Path]) -> None:
    modules = [
        package_of(p) + ("" if p.stem == "__init__" else f".{p.stem}")
        for folder in folders
        for p in sources(folder)
        if p.stem != "__main__"
    ]
    result = run_without_torch(
        f"import importlib\nfor m in {modules!r}:\n"
        "    importlib.import_module(m)\nprint('ok', len(sys.modules))\n",
        block_export=False,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("ok")


def test_the_runtime_and_the_quality_bench_import_with_torch_unimportable(run_without_torch):
    import_every_module_without_torch(run_without_torch, [RUNTIME_DIR, ROOT / "bench" / "quality"])


def test_the_export_data_room_imports_with_torch_unimportable(run_without_torch):
    import_every_module_without_torch(run_without_torch, [ROOT / "export" / "data"])


def test_the_public_api_is_at_the_package_top(run_without_torch):
    result = run_without_torch(
        "from mogo import MotionGenerator, MotionStream, Motion, Sampling\n"
        "import mogo\nprint(sorted(mogo.__all__))\n"
    )
    assert result.returncode == 0, result.stderr
    assert "MotionGenerator" in result.stdout


def test_the_mogo_command_runs_its_runtime_verbs_without_torch(run_without_torch, tmp_path):
    result = run_without_torch(
        "from mogo.cli import main\n"
        f"code = main(['generate', 'a person waves.', '--seconds', '1', '--seed', '0', "
        f"'--out', {str(tmp_path)!r}])\n"
        "assert code == 0, code\n",
        block_export=False,
    )
    assert result.returncode == 0, result.stderr
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".bvh", ".gif", ".json", ".npy"]


def test_the_runtime_tests_run_without_torch(run_without_torch):
    """tests/runtime/ checks the runtime as a user of the base install has it: no torch."""
    tests = Path(__file__).parent
    for path in sorted((tests / "runtime").glob("test_*.py")):
        done = run_without_torch(
            f"import runpy\nsys.path.insert(0, {str(tests)!r})\nrunpy.run_path({str(path)!r})\n"
        )
        assert done.returncode == 0, f"{path.name}: {done.stderr[-2000:]}"
