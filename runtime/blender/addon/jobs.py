"""Long work off Blender's UI thread, with its progress in the status bar, and every error as
one line in Blender's report area (never a traceback in the user's face)."""

from __future__ import annotations

import functools
import threading
import time

import bpy


class UserError(Exception):
    """Something the user can fix: reported as it is."""


def one_line(error: BaseException) -> str:
    """An error as the one line a report shows: its message (a ValueError from the runtime
    names the argument), else its type."""
    lines = str(error).strip().splitlines()
    return lines[0] if lines else type(error).__name__


def reported(method):
    """An operator's execute/invoke whose errors become one ERROR report and CANCELLED."""

    @functools.wraps(method)
    def run(self, context, *args):
        try:
            return method(self, context, *args)
        except Exception as error:  # noqa: BLE001 - the report is the user's error message
            self.report({"ERROR"}, f"MOGO: {one_line(error)}")
            return {"CANCELLED"}

    return run


class Background:
    """An operator mix-in: prepare(context) on the UI thread, work() on a thread (no bpy
    there), finish(context, result) back on the UI thread. Blender run headless (-b) has no
    event loop for a modal operator, so there the work runs in place."""

    label = "working"
    _thread = _timer = None

    @reported
    def execute(self, context):
        self.prepare(context)
        if bpy.app.background:
            self.finish(context, self.work())
            return {"FINISHED"}
        self._result, self._error, self._started = None, None, time.monotonic()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        manager = context.window_manager
        self._timer = manager.event_timer_add(0.25, window=context.window)
        manager.modal_handler_add(self)
        manager.progress_begin(0, 100)
        return {"RUNNING_MODAL"}

    def _run(self):
        try:
            self._result = self.work()
        except Exception as error:  # noqa: BLE001 - reported on the UI thread
            self._error = error

    def modal(self, context, event):
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        elapsed = time.monotonic() - self._started
        if self._thread.is_alive():
            context.workspace.status_text_set(f"MOGO: {self.label}... {elapsed:.0f} s")
            context.window_manager.progress_update(min(99, int(elapsed)))
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        context.window_manager.progress_end()
        context.workspace.status_text_set(None)
        if self._error is not None:
            self.report({"ERROR"}, f"MOGO: {one_line(self._error)}")
            return {"CANCELLED"}
        return self._finish_reported(context)

    @reported
    def _finish_reported(self, context):
        self.finish(context, self._result)
        return {"FINISHED"}

    def prepare(self, context):
        """UI thread, before the work: read the scene, check inputs."""

    def work(self):
        raise NotImplementedError

    def finish(self, context, result):
        """UI thread, after the work: write into the scene."""
