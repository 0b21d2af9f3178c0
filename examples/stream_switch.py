"""An endless stream with a prompt switch: frames come as they are made, 20 a second.

    python examples/stream_switch.py

Prints where the pelvis is once a second: jogging forward for 5 s, then walking backward.
"""

from mogo import MotionGenerator

generator = MotionGenerator.load(threads=2)
stream = generator.stream("a person jogs forward", seed=1)  # endless: stop when you like
for n, frame in enumerate(stream.frames(200)):  # frame: (22, 3) joints, metres, Y up
    if n == 100:
        stream.set_prompt("a person walks backward")  # from the next token step on
    if n % 20 == 0:
        x, y, z = frame[0]  # joint 0 is the pelvis
        print(f"{n / 20:4.1f} s  pelvis x {x:+.2f} m, height {y:.2f} m, z {z:+.2f} m")
