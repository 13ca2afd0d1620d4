"""A small Shapes Demo: publish a moving circle, or print the circles others publish.

    python -m automotive.tools.shapes.shapes publish --color BLUE [--shapesize 30]
    python -m automotive.tools.shapes.shapes subscribe

Same topic (Circle), type (ShapeType: color key, x, y, shapesize; appendable) and QoS conventions as RTI Shapes
Demo (the DDS defaults: reliable writer, best-effort reader; XCDR1 on the wire, which RTI readers accept), so it
talks to RTI Shapes Demo, to the OMG interoperability shape application, and to our LiDAR.

The publisher moves its circle inside the 240 x 270 Shapes Demo box as the OMG DDS-RTPS interoperability shape
application does: config.speed pixels along each axis every config.pubInterval ms (3 px every 33 ms: about 90 px
a second), bouncing off the walls, from a random position in a random diagonal direction. When it stops, its
writer is deleted, which disposes the circle: subscribers see it go.
"""

from __future__ import annotations

import argparse
import random
import sys
from typing import Any

from cyclonedds.core import InstanceState

from automotive.bus.app import Application, run
from automotive.bus.errors import ConfigError
from automotive.bus.properties import PropertyKeys
from automotive.bus.samplerules import CANVAS_HEIGHT, CANVAS_WIDTH
from automotive.types.automotive import ShapeType

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of("config.pubInterval", "config.speed", "config.shapesize", roles=["Shapes"])

BOX_WIDTH, BOX_HEIGHT = CANVAS_WIDTH, CANVAS_HEIGHT
GONE_STATES = {
    InstanceState.NotAliveDisposed: "disposed",
    InstanceState.NotAliveNoWriters: "no writers left",
}


class MovingShape:
    """A circle bouncing inside the Shapes Demo box; its centre stays at least half its size from every wall."""

    def __init__(self, color: str, size: int, speed: int, rng: random.Random):
        self.color = color
        self.size = size
        margin = self.margin
        self.x = rng.randint(margin, BOX_WIDTH - margin)
        self.y = rng.randint(margin, BOX_HEIGHT - margin)
        self.vx = speed * rng.choice((-1, 1))
        self.vy = speed * rng.choice((-1, 1))

    @property
    def margin(self) -> int:
        return min(1 + self.size // 2, BOX_WIDTH // 2)

    def step(self) -> None:
        margin = self.margin
        self.x, self.vx = self._bounce(self.x + self.vx, self.vx, margin, BOX_WIDTH - margin)
        self.y, self.vy = self._bounce(self.y + self.vy, self.vy, margin, BOX_HEIGHT - margin)

    @staticmethod
    def _bounce(position: int, velocity: int, low: int, high: int) -> tuple[int, int]:
        if position < low:
            return low, abs(velocity)
        if position > high:
            return max(low, high), -abs(velocity)
        return position, velocity

    def sample(self) -> ShapeType:
        return ShapeType(color=self.color, x=self.x, y=self.y, shapesize=self.size)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mode", choices=["publish", "subscribe"], help="publish a moving circle, or print circles")
    parser.add_argument("--color", default="BLUE",
                        help="colour (the instance key) to publish: BLUE, GREEN, RED, CYAN, MAGENTA, PURPLE, ORANGE, "
                             "YELLOW (default BLUE)")
    parser.add_argument("--shapesize", type=int, default=None, help="size in pixels (default config.shapesize, 30)")


def publish(app: Application, interval_s: float, speed: int, size: int) -> None:
    color = app.args.color.strip().upper()
    if not color:
        raise ConfigError("--color: expected a colour name such as BLUE")
    writer = app.writer("Shapes", ShapeType, "Circle")
    shape = MovingShape(color, size, speed, random.Random())
    app.log.info("publishing %s %s, size %d, %d px every %.0f ms", color, writer.topic.name, size, speed,
                 interval_s * 1000)
    for iteration in app.periodic(interval_s):
        shape.step()
        writer.write(shape.sample())
        if iteration == 1 or iteration % 30 == 0:
            app.log.info("%s %s at (%d, %d), sample %d", writer.topic.name, color, shape.x, shape.y, iteration)


def sample_color(sample: Any) -> str:
    key = sample if sample.sample_info.valid_data else sample.key_sample
    return str(getattr(key, "color", "?"))


def subscribe(app: Application) -> None:
    reader = app.reader("Shapes", ShapeType, "Circle")
    topic = reader.topic.name
    app.log.info("subscribing to %s", topic)
    seen: set[str] = set()
    for _ in app.wake_ups(app.waitset(reader)):
        gone: dict[str, str] = {}  # colour -> why, once per take (the data and the disposal may come together)
        for sample in reader.take(N=256):
            info = sample.sample_info
            color = sample_color(sample)
            if info.valid_data:
                if color not in seen:
                    app.log.info("new shape: %s %s", topic, color)
                    seen.add(color)
                app.log.info("%s %s x=%d y=%d size=%d", topic, color, sample.x, sample.y, sample.shapesize)
                app.tick()
            if info.instance_state in GONE_STATES:
                gone[color] = GONE_STATES[info.instance_state]
        for color, why in gone.items():
            seen.discard(color)
            app.log.info("%s %s %s", topic, color, why)


def body(app: Application) -> None:
    # Read every setting in either mode: a key the file holds but no mode reads would be reported as unknown.
    interval_s = app.props.get_float("config.pubInterval", 33, minimum=1) / 1000
    speed = app.props.get_int("config.speed", 3, minimum=0, maximum=100)
    size = app.props.get_int("config.shapesize", 30, minimum=1, maximum=BOX_WIDTH)
    if app.args.shapesize is not None:
        if not 1 <= app.args.shapesize <= BOX_WIDTH:
            raise ConfigError(f"--shapesize {app.args.shapesize}: expected 1..{BOX_WIDTH} pixels")
        size = app.args.shapesize
    if app.args.mode == "publish":
        publish(app, interval_s, speed, size)
    else:
        subscribe(app)


def main(argv: list[str] | None = None) -> int:
    return run("shapes", __doc__ or "", body, argv, add_arguments, command="automotive shapes-demo",
               keys=PROPERTY_KEYS)


if __name__ == "__main__":
    sys.exit(main())
