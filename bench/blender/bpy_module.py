"""Runs a `blender -b --python SCRIPT -- ARGS` script under the `bpy` module from PyPI (Blender
as a Python module: the wheels for Blender 4.x, which bring no blender executable), so the same
scene scripts check the add-on on the Blender versions a distribution does not package.

    PYTHON bench/blender/bpy_module.py SCRIPT -- ARGS
PYTHON: a Python with `pip install bpy==4.x` (its own environment: the wheel is ~350 MB).
"""

import os
import runpy
import sys

import bpy  # noqa: F401 - Blender starts here, as `blender -b` would before the script


def main() -> None:
    script = sys.argv[1]
    sys.argv = [script] + sys.argv[2:]  # the script reads its arguments after "--", as in Blender
    runpy.run_path(script, run_name="__main__")  # an error propagates: a traceback, status 1
    # After a full add-on run, bpy 4.5.0 hangs in its exit handlers (4.2, 4.3, 4.4 and 5.0 do
    # not; a bare `import bpy` exits): the script is done and wrote its result, so leave now.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


if __name__ == "__main__":
    main()
