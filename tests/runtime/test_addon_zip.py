"""`mogo blender-addon`: the add-on zip Blender installs, written whole, never over a file, with
this runtime's wheel for the add-on's Install (never PyPI's unrelated `mogo`)."""

import ast
import dataclasses
import io
import subprocess
import sys
import zipfile

import pytest

from mogo.blender.addon_zip import FOLDER, GENERATED, SOURCE, addon_bytes, runtime_wheel
from mogo.cli import main
from mogo.sampling import Sampling, SamplingError


def test_the_zip_holds_the_addon_folder_and_is_the_same_on_every_build():
    data = addon_bytes()
    assert data == addon_bytes()
    names = zipfile.ZipFile(io.BytesIO(data)).namelist()
    wheel, _ = runtime_wheel()
    assert not (SOURCE / GENERATED).exists()  # written into the zip only
    assert sorted(names) == sorted(
        [f"{FOLDER}/{p.name}" for p in SOURCE.glob("*.py")]
        + [f"{FOLDER}/{GENERATED}", f"{FOLDER}/{wheel}"]
    )
    init = ast.parse((SOURCE / "__init__.py").read_text())
    info = next(n for n in init.body if isinstance(n, ast.Assign) and n.targets[0].id == "bl_info")
    assert ast.literal_eval(info.value)["blender"] == (3, 4, 0)


def test_the_command_writes_the_zip_and_keeps_an_existing_file(tmp_path, capsys):
    out = tmp_path / "mogo_blender.zip"
    assert main(["blender-addon", "--out", str(out)]) == 0
    assert out.read_bytes() == addon_bytes()
    out.write_bytes(b"mine")
    capsys.readouterr()
    assert main(["blender-addon", "--out", str(out)]) == 2
    assert out.read_bytes() == b"mine"
    assert capsys.readouterr().err == f"mogo: error: {out}: exists (--overwrite replaces it)\n"
    assert main(["blender-addon", "--out", str(out), "--overwrite"]) == 0
    assert out.read_bytes() == addon_bytes() and not list(tmp_path.glob(".*"))
    assert main(["blender-addon", "--out", str(tmp_path / "addon.tar")]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "must end in .zip" in error


def test_the_shipped_wheel_is_this_runtime_and_pip_installs_it(tmp_path):
    name, data = runtime_wheel()
    assert name.startswith("mogo_edge-") and name.endswith("-py3-none-any.whl")
    (tmp_path / name).write_bytes(data)
    target = tmp_path / "packages"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--no-deps",
            "--no-index",
            "--target",
            str(target),
            str(tmp_path / name),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    (info,) = target.glob("mogo_edge-*.dist-info")
    metadata = (info / "METADATA").read_text()
    assert "Name: mogo-edge\n" in metadata
    requirements = sorted(
        line.split(": ")[1].split(">")[0]
        for line in metadata.splitlines()
        if line.startswith("Requires-Dist")
    )
    assert requirements == ["numpy", "onnxruntime", "pillow", "tokenizers"]  # no extra
    assert (target / "mogo" / "generator.py").is_file()
    assert (target / "mogo" / "default_bundle" / "manifest.json").is_file()
    assert not [name for name in ("export", "bench", "web") if (target / "mogo" / name).exists()]
    # what was installed imports as this runtime (the dependencies from this environment)
    check = "import mogo, sys; print(mogo.__file__); assert mogo.MotionGenerator"
    done = subprocess.run(
        [sys.executable, "-c", check],
        capture_output=True,
        text=True,
        env={"PYTHONPATH": str(target)},
        timeout=60,
    )
    assert done.returncode == 0 and done.stdout.startswith(str(target)), done.stderr


def test_the_panels_sampling_options_are_samplings_own():
    """The zip's sampling.py (the panel's options, their defaults and limits) is Sampling's, and
    each limit is where Sampling starts refusing: the panel offers no value the runtime refuses
    but top_p = 0, the open end it cannot show."""
    written = zipfile.ZipFile(io.BytesIO(addon_bytes())).read(f"{FOLDER}/{GENERATED}").decode()
    options = {}
    exec(compile(written, GENERATED, "exec"), options)  # our own generated source
    fields = {f.name: f for f in dataclasses.fields(Sampling)}
    assert [option[0] for option in options["OPTIONS"]] == list(fields)
    for name, kind, default, low, high, help in options["OPTIONS"]:
        assert (kind, default, help) == (
            type(fields[name].default).__name__,
            fields[name].default,
            fields[name].metadata["help"],
        )
        step = 1 if kind == "int" else 1e-3
        with pytest.raises(SamplingError):
            Sampling(**{name: low - step})
        if name == "top_p":
            with pytest.raises(SamplingError):
                Sampling(top_p=low)
        else:
            Sampling(**{name: low})
        if high is not None:
            Sampling(**{name: high})
            with pytest.raises(SamplingError):
                Sampling(**{name: high + step})
