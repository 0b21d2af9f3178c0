"""Live mode: a MotionStream runs on a thread (the runtime's own streaming, rotations solved by
its rig), a Blender timer writes what it made as keys while the timeline plays, a new prompt
switches the stream mid-motion, and stopping keeps the keys as an Action."""

from __future__ import annotations

import queue
import threading
import time

import bpy
import numpy as np

from . import scene as our_scene
from .jobs import one_line
from .motion_keys import C

AHEAD_SECONDS = 1.0  # the stream runs at most this far ahead of the playhead
TICK = 0.05  # seconds between timer calls


class LiveSession:
    """One live take on our armature: motion frame n keyed at scene frame start + n * step."""

    def __init__(self, generator, ours, armature, action, stream, start: int, step: float):
        self.ours, self.armature, self.action, self.stream = ours, armature, action, stream
        self.fps = generator.fps
        self.start, self.step, self.written, self.made = start, step, 0, 0
        self.prompts: queue.Queue[str] = queue.Queue()
        self.chunks: queue.Queue = queue.Queue()
        self.stop_event = threading.Event()
        self.error: BaseException | None = None
        self.playhead = start
        self.last_keys = None
        self.thread = threading.Thread(target=self._produce, daemon=True)
        self.thread.start()
        bpy.app.timers.register(self.tick, first_interval=TICK)

    def _produce(self) -> None:
        """The thread: steps of the stream, each chunk's rotations solved here (numpy)."""
        try:
            while not self.stop_event.is_set():
                while not self.prompts.empty():
                    self.stream.set_prompt(self.prompts.get())
                ahead = self.start + self.made * self.step - self.playhead
                if ahead > AHEAD_SECONDS * self.fps * self.step:
                    time.sleep(TICK)
                    continue
                frames = self.stream.step()
                if len(frames):
                    self.chunks.put((frames, self.ours.world(frames)))
                    self.made += len(frames)
        except Exception as error:  # noqa: BLE001 - shown by the timer on the UI thread
            self.error = error

    def tick(self) -> float | None:
        """The timer (UI thread): keys for every finished chunk; None ends the timer."""
        self.playhead = bpy.context.scene.frame_current
        self.flush()
        if self.error is not None:
            bpy.context.workspace.status_text_set(f"MOGO live stopped: {one_line(self.error)}")
            print(f"MOGO live stopped: {one_line(self.error)}")
            return None
        return None if self.stop_event.is_set() else TICK

    def flush(self) -> int:
        """Write the waiting chunks as keys; the frames written so far."""
        while not self.chunks.empty():
            joints, world = self.chunks.get()
            frames = self.start + (self.written + np.arange(len(joints))) * self.step
            self.last_keys = our_scene.write_pose(
                self.action,
                self.armature,
                self.ours,
                world,
                joints[:, 0] @ C.T,
                frames,
                self.last_keys,
            )
            self.written += len(joints)
            bpy.context.scene.frame_end = max(bpy.context.scene.frame_end, int(np.ceil(frames[-1])))
        return self.written

    def switch(self, prompt: str) -> None:
        self.prompts.put(prompt)

    def stop(self) -> int:
        """End the stream; what was streamed stays as the Action. The frames kept."""
        self.stop_event.set()
        self.thread.join(timeout=30)
        if bpy.app.timers.is_registered(self.tick):
            bpy.app.timers.unregister(self.tick)
        return self.flush()
