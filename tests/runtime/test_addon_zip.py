"""`mogo blender-addon`: the add-on zip Blender installs, written whole, never over a file."""
import ast
import io
import zipfile

from mogo.addon_zip import FOLDER, SOURCE, addon_bytes
from mogo.cli import main


def test_the_zip_holds_the_addon_folder_and_is_the_same_on_every_build():
    data = addon_bytes()
    assert data == addon_bytes()
    names = zipfile.ZipFile(io.BytesIO(data)).namelist()
    assert sorted(names) == sorted(f"{FOLDER}/{p.name}" for p in SOURCE.glob("*.py"))
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
