"""Write the pre-canned data of the vision sensor and the vehicle platform: OUT/{vision,platform}.csv.

The scene: 100 s (1000 samples at 10 Hz) of the ego car on a two-lane town road, on a gently winding route. The ego
follows a car in its lane at 45 km/h or so, meets oncoming traffic, overtakes cyclists in the bike lane, passes parked
cars and pedestrians on both sidewalks. About every 20 s something big is close ahead for under a second: a truck or
a bus crossing at an intersection (seen only between the corner buildings), or a road-works barrier that a parked van
hid until the last metres. These are the only objects wider than 2 m, so collision avoidance's rule (an object with
size[1] > 2.0) fires once per such episode and clears after it; the driver brakes a little each time.

Frames: world x along the road, y to the left; the camera sits at the ego's origin looking along x. A vision object's
position is relative to the camera (position[2]: height of the object's centre above the road), its velocity is
relative to the ego, and its size is the box it occupies along x, y, z of that frame (size[1]: how wide it looks).

The files follow the original example's CSV formats (same header style and columns); the output is a function of
--seed alone. The shipped files (automotive/config/properties/data) were made with the defaults:
``python -m automotive.tools.support.make_scene_data --out src/automotive/config/properties/data`` in a clone of the
repository.
"""

from __future__ import annotations

import calendar
import csv
import math
import random
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from automotive.bus.cli import ArgumentParser

DT = 0.1  # s between samples (the applications' default publication period)
START = calendar.timegm((2024, 5, 14, 9, 30, 0))  # 2024-05-14 09:30:00 UTC
TAN_HALF_FOV = math.tan(math.radians(25))  # the camera sees 25 degrees to either side
MAX_OBJECTS = 10

# Classification values (Common::ClassificationEnum)
UNKNOWN, UNKNOWNSMALL, UNKNOWNBIG, PEDESTRIAN, BIKE, CAR, TRUCK, BARRIER = range(8)
# Detection range by classification: small things are recognised later
RANGE = {PEDESTRIAN: 40.0, BIKE: 60.0, CAR: 80.0, TRUCK: 80.0, BARRIER: 40.0}

# Lateral positions (m, left positive) of the road's parts
EGO_LANE, ONCOMING_LANE, BIKE_LANE, PARKING, RIGHT_WALK, LEFT_WALK = 0.0, 3.2, -2.3, -4.1, -6.2, 5.8

CAR_BOX = (4.5, 1.8, 1.5)
VAN_BOX = (5.2, 1.95, 2.4)  # just under the alert width: a van alone is no reason to alert
BIKE_BOX = (1.8, 0.7, 1.7)
PEDESTRIAN_BOX = (0.5, 0.6, 1.75)


@dataclass
class Agent:
    track: int
    classification: int
    box: tuple[float, float, float]  # extent along the ego frame's x, y, z
    x: Callable[[float], float]  # world position over time
    y: Callable[[float], float]
    alive: tuple[float, float] = (-math.inf, math.inf)
    visible: Callable[[float, float], bool] = field(default=lambda rel_x, rel_y: True)  # occlusion by the scenery


def smooth_bump(t: float, centre: float, width: float) -> float:
    """1 at centre, falling smoothly to 0 (a Gaussian of the given standard deviation)."""
    return math.exp(-0.5 * ((t - centre) / width) ** 2)


class Scene:
    def __init__(self, seed: int, rows: int):
        self.rng = random.Random(seed)
        self.rows = rows
        self.duration = rows * DT
        rng = self.rng
        # One episode about every 20 s, jittered; the first and last sit about 10 s from the file's ends, so that the
        # gap across the wrap-around is like the others.
        count = max(1, round(self.duration / 20))
        spacing = self.duration / count
        self.episodes = [spacing * (i + 0.5) + rng.uniform(-1.5, 1.5) for i in range(count)]
        self.phases = [rng.uniform(0, 2 * math.pi) for _ in range(6)]
        self._ego_x = self._integrate_ego()
        self.agents: list[Agent] = []
        self._next_track = 1
        self._populate()

    # --- ego motion -------------------------------------------------------------------------------------------------
    def ego_speed(self, t: float) -> float:
        """m/s: cruising around 12.5 with slow swells (periods dividing the file's length, so the loop is smooth)
        and a short braking dip after each episode."""
        p = self.phases
        period = self.duration
        v = (12.5 + 1.6 * math.sin(2 * math.pi * t / (period / 2) + p[0])
             + 0.9 * math.sin(2 * math.pi * t / (period / 5) + p[1])
             + 0.4 * math.sin(2 * math.pi * t / (period / 8) + p[2]))
        # The driver brakes within a second of seeing the obstacle and takes a few seconds to get back to speed.
        return v - sum(2.5 * smooth_bump(t, centre + 1.3, 0.7 if t < centre + 1.3 else 2.5) for centre in self.episodes)

    def curvature(self, t: float) -> float:
        """1/m of the road under the ego: gentle bends, radius 500 m and more."""
        p = self.phases
        return (0.0012 * math.sin(2 * math.pi * t / (self.duration / 2) + p[3])
                + 0.0006 * math.sin(2 * math.pi * t / (self.duration / 4) + p[4]))

    def _integrate_ego(self) -> list[float]:
        # Fine steps, so that positions between samples (for the agents' set-up) are accurate enough.
        steps = 10
        xs = [0.0]
        h = DT / steps
        for i in range((self.rows + 200) * steps):
            t = i * h - 100 * DT
            xs.append(xs[-1] + h * 0.5 * (self.ego_speed(t) + self.ego_speed(t + h)))
        self._ego_step = h
        return xs

    def ego_x(self, t: float) -> float:
        position = (t + 100 * DT) / self._ego_step
        i = min(max(int(position), 0), len(self._ego_x) - 2)
        frac = position - i
        return self._ego_x[i] * (1 - frac) + self._ego_x[i + 1] * frac

    # --- the other road users ---------------------------------------------------------------------------------------
    def _add(self, classification: int, box: tuple[float, float, float], x: Callable[[float], float],
             y: Callable[[float], float], **extra: object) -> None:
        self.agents.append(Agent(self._next_track, classification, box, x, y, **extra))  # type: ignore[arg-type]
        self._next_track = self._next_track % 255 + 1

    def _near_episode(self, t: float, margin: float) -> bool:
        return any(abs(t - centre) < margin for centre in self.episodes)

    def _populate(self) -> None:
        rng = self.rng
        end = self.duration

        # The car ahead in the ego lane; it pulls away before each episode, so the crossing happens between the two.
        lead_phase = rng.uniform(0, 6.3)

        def lead_gap(t: float) -> float:
            return (26 + 5 * math.sin(2 * math.pi * t / 25 + lead_phase)
                    + sum(14 * smooth_bump(t, centre, 3.0) for centre in self.episodes))

        self._add(CAR, CAR_BOX, lambda t: self.ego_x(t) + lead_gap(t),
                  lambda t: EGO_LANE + 0.15 * math.sin(t / 3.1))

        # Oncoming traffic: a car every 3 to 9 s, 40 to 50 km/h
        t = -8.0
        while t < end:
            speed = rng.uniform(11, 14)
            start, x0, offset = t, self.ego_x(t) + 110, rng.uniform(-0.2, 0.2)
            self._add(CAR, CAR_BOX, lambda t, x0=x0, s=start, v=speed: x0 - v * (t - s),  # type: ignore[misc]
                      lambda t, o=offset: ONCOMING_LANE + o, alive=(start, start + 12))  # type: ignore[misc]
            t += rng.uniform(3, 9)

        # Cyclists in the bike lane, overtaken by the ego away from the episodes
        for pass_time in (14.0, 36.0, 57.0, 82.0):
            while self._near_episode(pass_time, 4.0):
                pass_time += 2.0
            speed = rng.uniform(4.5, 6.0)
            x0, offset = self.ego_x(pass_time) - speed * pass_time, rng.uniform(-0.2, 0.2)
            self._add(BIKE, BIKE_BOX, lambda t, x0=x0, v=speed: x0 + v * t, lambda t, o=offset: BIKE_LANE + o)  # type: ignore[misc]

        # Parked cars in the bays on the right, in a few stretches
        x_end = self.ego_x(end) + 100
        x = self.ego_x(0) + 15
        while x < x_end:
            if rng.random() < 0.45:
                for _ in range(rng.randint(1, 3)):
                    self._add(CAR, CAR_BOX, lambda t, x=x: x, lambda t: PARKING)  # type: ignore[misc]
                    x += rng.uniform(6, 8)
            x += rng.uniform(30, 90)

        # Pedestrians on both sidewalks, walking either way at 1.1 to 1.5 m/s
        x = self.ego_x(0) + 5
        while x < x_end:
            side = rng.choice((RIGHT_WALK, LEFT_WALK))
            speed = rng.choice((-1, 1)) * rng.uniform(1.1, 1.5)
            for k in range(1 if rng.random() < 0.8 else 2):  # now and then two walk together
                self._add(PEDESTRIAN, PEDESTRIAN_BOX, lambda t, x0=x + 0.8 * k, v=speed: x0 + v * t,  # type: ignore[misc]
                          lambda t, y=side + 0.7 * k: y)  # type: ignore[misc]
            x += rng.uniform(20, 60)

        for i, centre in enumerate(self.episodes):
            if i % 2 == 0:
                self._crossing(centre, bus=(i % 4 == 2))
            else:
                self._roadworks(centre)

    def _crossing(self, centre: float, bus: bool) -> None:
        """A truck (or bus) crosses an intersection 20 m ahead; corner buildings hide it beyond 4.6 m either side."""
        rng = self.rng
        x_cross = self.ego_x(centre) + rng.uniform(18, 22)
        direction = rng.choice((-1, 1))
        speed = rng.uniform(11, 13)
        length = 12.0 if bus else 9.5
        width = 2.55 if bus else 2.5
        # It moves across the ego's view, so it looks as wide as it is long.
        self._add(TRUCK, (width, length, 3.2 if bus else 3.5), lambda t: x_cross,
                  lambda t: direction * speed * (t - centre), alive=(centre - 2, centre + 2),
                  visible=lambda rel_x, rel_y: abs(rel_y) <= 4.6)

    def _roadworks(self, centre: float) -> None:
        """A barrier closing the bike lane just beside the ego lane, behind a parked van that hides it until the ego is
        12.5 m away; it leaves the camera's field of view a few metres later."""
        x_barrier = self.ego_x(centre) + 8.5
        self._add(CAR, VAN_BOX, lambda t: x_barrier - 7.0, lambda t: BIKE_LANE - 0.1)
        self._add(BARRIER, (0.4, 2.2, 1.0), lambda t: x_barrier, lambda t: BIKE_LANE - 0.1,
                  visible=lambda rel_x, rel_y: rel_x <= 12.5)

    # --- sampling ---------------------------------------------------------------------------------------------------
    def vision_row(self, k: int) -> list[tuple[int, int, list[float], list[float], tuple[float, float, float]]]:
        t = k * DT
        ego_x, ego_v = self.ego_x(t), self.ego_speed(t)
        seen = []
        for agent in self.agents:
            if not agent.alive[0] <= t <= agent.alive[1]:
                continue
            rel_x, rel_y = agent.x(t) - ego_x, agent.y(t)
            if not (1.0 < rel_x <= RANGE[agent.classification] and abs(rel_y) <= rel_x * TAN_HALF_FOV
                    and agent.visible(rel_x, rel_y)):
                continue
            h = 0.05  # central difference for the agent's world velocity
            vx = (agent.x(t + h) - agent.x(t - h)) / (2 * h)
            vy = (agent.y(t + h) - agent.y(t - h)) / (2 * h)
            seen.append((agent.track, agent.classification, [rel_x, rel_y, agent.box[2] / 2],
                         [vx - ego_v, vy, 0.0], agent.box))
        seen.sort(key=lambda obj: math.hypot(obj[2][0], obj[2][1]))
        return seen[:MAX_OBJECTS]

    def platform_row(self, k: int) -> tuple[float, float, float, float]:
        t = k * DT
        v = self.ego_speed(t)
        accel = (self.ego_speed(t + DT / 2) - self.ego_speed(t - DT / 2)) / DT
        yaw_rate = v * self.curvature(t) + self.rng.gauss(0, 0.0004)  # gyro noise
        # Gas pedal: what holds the speed against drag, plus what accelerates; released to slow down.
        pedal = min(max(round(9 + 1.6 * v + 45 * accel + self.rng.uniform(-1, 1)), 0), 100)
        return v, yaw_rate, v * 3.6, pedal


def number(value: float, decimals: int = 4) -> str:
    text = f"{value:.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if text in ("", "-0") else text


def timestamps(k: int) -> list[str]:
    seconds = START + k * DT
    return [time.strftime("%a %b %d %H:%M:%S %Y", time.gmtime(seconds)), f"{seconds * 1e6:.5E}"]


def write_vision(scene: Scene, path: Path) -> list[int]:
    header = ["Timestamp", "timeStamp"]
    for i in range(MAX_OBJECTS):
        header += [f"object[{i}].id", f"object[{i}].classification"]
        header += [f"object[{i}].{name}[{j}]" for name in ("position", "velocity", "size") for j in range(3)]
    header.append("numObjects")
    counts = []
    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow(header)
        for k in range(scene.rows):
            objects = scene.vision_row(k)
            cells = timestamps(k)
            for track, classification, position, velocity, size in objects:
                cells += [str(track), str(classification)]
                cells += [number(value) for value in (*position, *velocity, *size)]
            cells += ["0"] * (11 * (MAX_OBJECTS - len(objects)))  # unused slots are zeros, as in the original
            cells.append(str(len(objects)))
            writer.writerow(cells)
            counts.append(len(objects))
    return counts


def write_platform(scene: Scene, path: Path) -> None:
    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow(["Timestamp", "timeStamp", "velocity", "yawRate", "vehSpd", "posGasPedal"])
        for k in range(scene.rows):
            velocity, yaw_rate, speed, pedal = scene.platform_row(k)
            writer.writerow(timestamps(k) + [number(velocity), number(yaw_rate, 6), number(speed, 3), number(pedal)])


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m automotive.tools.support.make_scene_data",
                            description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seed", type=int, default=20240514, help="random seed (default: %(default)s)")
    parser.add_argument("--rows", type=int, default=1000, help="samples per file, 10 per second (default: %(default)s)")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    args = parser.parse_args(argv)
    if args.rows < 100:
        parser.error(f"--rows {args.rows}: expected at least 100")
    args.out.mkdir(parents=True, exist_ok=True)
    scene = Scene(args.seed, args.rows)
    counts = write_vision(scene, args.out / "vision.csv")
    write_platform(scene, args.out / "platform.csv")
    print(f"wrote {args.rows} rows to {args.out / 'vision.csv'} ({sum(counts) / len(counts):.1f} objects per row, "
          f"at most {max(counts)}) and {args.out / 'platform.csv'}; episodes at "
          + ", ".join(f"{centre:.1f} s" for centre in scene.episodes))
    return 0


if __name__ == "__main__":
    sys.exit(main())
