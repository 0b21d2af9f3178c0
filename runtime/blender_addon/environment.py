"""Getting the MOGO runtime into Blender's Python: a folder of packages (the add-on's own,
filled by Install with Blender's Python and pip, or a Python environment's site-packages the
user points at), added to sys.path; and one clear line when something is missing."""

import importlib
import os
import site
import subprocess
import sys

import bpy

from .jobs import Background, UserError

PACKAGES = ("numpy", "onnxruntime", "tokenizers", "PIL", "mogo")


def addon_preferences(context=None):
    context = context or bpy.context
    return context.preferences.addons[__package__].preferences


def own_folder() -> str:
    """The add-on's package folder in Blender's user files (what Install fills)."""
    return bpy.utils.user_resource("SCRIPTS", path="mogo_runtime", create=True)


def packages_folder(context=None) -> str:
    return bpy.path.abspath(addon_preferences(context).site_packages) or own_folder()


def runtime(context=None):
    """The runtime's `mogo` module, the packages folder on sys.path first; a UserError naming
    what is missing and how to get it otherwise."""
    folder = packages_folder(context)
    if os.path.isdir(folder) and folder not in sys.path:
        site.addsitedir(folder)  # .pth files too: an editable install in a venv works
        importlib.invalidate_caches()
    missing = [name for name in PACKAGES if not _importable(name)]
    if missing:
        version = f"{sys.version_info.major}.{sys.version_info.minor}"
        raise UserError(
            f"MOGO runtime not found ({', '.join(missing)} missing in {folder}): press Install "
            f"in Preferences > Add-ons > MOGO, or set 'Packages folder' to the site-packages of "
            f"a Python {version} environment with mogo installed")
    import mogo
    return mogo


def _importable(name: str) -> bool:
    try:
        importlib.import_module(name)
    except ImportError:
        return False
    return True


def pip_commands(source: str, folder: str) -> list[list[str]]:
    """Blender's own Python: pip (bootstrapped by ensurepip where it lacks one), then the
    runtime with its dependencies into the packages folder."""
    python = sys.executable
    return [[python, "-m", "ensurepip", "--upgrade"],
            [python, "-m", "pip", "install", "--upgrade", "--target", folder, source]]


class MOGO_OT_install_runtime(Background, bpy.types.Operator):
    """Install the MOGO runtime (numpy, onnxruntime, tokenizers, pillow, mogo) into the
    packages folder with Blender's own Python and pip"""
    bl_idname = "mogo.install_runtime"
    bl_label = "Install MOGO runtime"
    label = "installing the runtime with pip"

    def prepare(self, context):
        source = addon_preferences(context).source.strip()
        if not source:
            raise UserError("give what to install: 'mogo', a wheel file or a project folder")
        self.commands = pip_commands(bpy.path.abspath(source) if os.path.exists(
            bpy.path.abspath(source)) else source, packages_folder(context))

    def work(self):
        for command in self.commands:
            if "ensurepip" in command and _has_pip():
                continue
            done = subprocess.run(command, capture_output=True, text=True)
            if done.returncode:
                lines = (done.stderr or done.stdout).strip().splitlines() or ["no output"]
                raise UserError(f"{' '.join(command[1:4])} failed: {lines[-1]}")

    def finish(self, context, result):
        runtime(context)
        self.report({"INFO"}, f"MOGO runtime installed in {packages_folder(context)}")


def _has_pip() -> bool:
    return subprocess.run([sys.executable, "-m", "pip", "--version"],
                          capture_output=True).returncode == 0


class MOGO_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    site_packages: bpy.props.StringProperty(
        name="Packages folder", subtype="DIR_PATH",
        description="Where the runtime is: empty = the add-on's own folder (Install fills it); "
                    "or the site-packages of a Python environment of Blender's Python version "
                    "that has mogo installed")
    source: bpy.props.StringProperty(
        name="Install from", default="mogo",
        description="What pip installs: 'mogo' from PyPI, a mogo wheel file, or a project "
                    "folder")

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "site_packages")
        row = layout.row()
        row.prop(self, "source")
        row.operator(MOGO_OT_install_runtime.bl_idname, icon="IMPORT")
        try:
            mogo = runtime(context)
            layout.label(text=f"Runtime found: {os.path.dirname(mogo.__file__)}", icon="CHECKMARK")
        except UserError as error:
            layout.label(text=str(error), icon="ERROR")


CLASSES = (MOGO_OT_install_runtime, MOGO_AP_preferences)
