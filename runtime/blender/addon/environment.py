"""Getting the MOGO runtime into Blender's Python: a folder of packages (the add-on's own,
filled by Install with Blender's Python and pip, or a Python environment's site-packages the
user points at), added to sys.path; and one clear line when something is missing.

Install installs the runtime's wheel that `mogo blender-addon` put beside this file (or a wheel
or project folder the user picks), never a name from PyPI: PyPI's `mogo` is an unrelated
PyMongo wrapper, and this project's distribution is `mogo-edge`."""

import glob
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
            f"a Python {version} environment with mogo-edge installed"
        )
    import mogo

    if not hasattr(mogo, "MotionGenerator"):  # PyPI's `mogo`, a PyMongo wrapper
        raise UserError(
            f"the 'mogo' in {os.path.dirname(os.path.dirname(mogo.__file__))} is PyPI's "
            f"unrelated package, not MOGO: press Install in Preferences > Add-ons > MOGO"
        )
    return mogo


def _importable(name: str) -> bool:
    try:
        importlib.import_module(name)
    except ImportError:
        return False
    return True


def shipped_wheel() -> str:
    """The runtime's wheel inside this add-on ('' where the add-on was installed without)."""
    wheels = sorted(glob.glob(os.path.join(os.path.dirname(__file__), "mogo_edge-*.whl")))
    return wheels[-1] if wheels else ""


def pip_commands(source: str, folder: str) -> list[list[str]]:
    """Blender's own Python: pip (bootstrapped by ensurepip where it lacks one), then the
    runtime with its dependencies into the packages folder."""
    python = sys.executable
    return [
        [python, "-m", "ensurepip", "--upgrade"],
        [python, "-m", "pip", "install", "--upgrade", "--target", folder, source],
    ]


class MOGO_OT_install_runtime(Background, bpy.types.Operator):
    """Install the MOGO runtime (mogo-edge with numpy, onnxruntime, tokenizers, pillow) into
    the packages folder with Blender's own Python and pip"""

    bl_idname = "mogo.install_runtime"
    bl_label = "Install MOGO runtime"
    label = "installing the runtime with pip"

    def prepare(self, context):
        given = addon_preferences(context).source.strip()
        source = bpy.path.abspath(given) if given else shipped_wheel()
        if not os.path.exists(source):
            raise UserError(
                f"Install from: no such wheel file or project folder: {given}"
                if given
                else "this add-on ships no runtime wheel: set Install "
                "from to a mogo-edge wheel file or the project's folder"
            )
        self.commands = pip_commands(source, packages_folder(context))

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
    return (
        subprocess.run([sys.executable, "-m", "pip", "--version"], capture_output=True).returncode
        == 0
    )


class MOGO_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    site_packages: bpy.props.StringProperty(
        name="Packages folder",
        subtype="DIR_PATH",
        description="Where the runtime is: empty = the add-on's own folder (Install fills it); "
        "or the site-packages of a Python environment of Blender's Python version "
        "that has mogo-edge installed",
    )
    source: bpy.props.StringProperty(
        name="Install from",
        subtype="FILE_PATH",
        description="What pip installs: empty = the runtime shipped with this add-on; or a "
        "mogo-edge wheel file or the project's folder",
    )

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
