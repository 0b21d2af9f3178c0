"""A MotionStream read on one thread and switched from another (a UI thread, Blender's live
mode): each switch waits for the step under way, none is lost, the stream stays whole."""

import threading

import numpy as np

from mogo import MotionGenerator


def test_set_prompt_from_another_thread_while_frames_are_read():
    generator = MotionGenerator.load(threads=2)  # level graphs on a pool of their own too
    stream = generator.stream("a person walks forward", seed=7)
    errors, switches = [], 40

    def switch():
        try:
            for k in range(switches):
                stream.set_prompt(["a person jumps", "a person waves"][k % 2])
        except Exception as error:  # noqa: BLE001 - reported by the main thread
            errors.append(error)

    other = threading.Thread(target=switch)
    other.start()
    frames = np.array(list(stream.frames(120)))
    other.join(timeout=120)
    assert not other.is_alive() and errors == []
    assert frames.shape == (120, 22, 3) and np.isfinite(frames).all()
    assert len(stream.prompts) == 1 + switches
    assert len(list(stream.frames(40))) == 40  # the stream goes on after them
