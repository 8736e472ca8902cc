"""The drone's sensors over a world tile: what the harness hands an agent at each step.

:class:`SimulatedSensors` renders what a drone at one position sees over a world tile. The
agent gets its :meth:`~SimulatedSensors.handle`, a :class:`SensorHandle` implementing
:class:`skyvln_eval.sensing.Sensors`: it can turn in place and capture, and gets images and
the camera's geometry. The handle holds only a key into this module's table of live
simulators, never the world, so nothing an agent is given leads to the world through its
interface. In one Python process that is a boundary of interfaces, not of memory: code
that imports the simulator or calls private members (``SensorHandle._sensors()``) can
reach the world. tests/agent/test_boundary.py checks that the toolkit's agents do
neither; review an agent of your own the same way.

Channels of sensors the drone does not carry are not handed out: no depth without the
depth sensor; no semantic, instance or category images without the semantic camera. The
semantic camera reports each landmark instance's category (as a simulator's panoptic
segmentation does), not its name or description, under a number of the capture's own,
not the world's id of the landmark.
"""

from __future__ import annotations

import itertools
import threading
import weakref
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from skyvln_eval.errors import PerceptionError
from skyvln_eval.frames import compass_to_enu_yaw_rad
from skyvln_eval.sensing import (
    CameraConfig,
    CameraImages,
    CameraPose,
    SensorConfig,
    SensorKind,
    instance_pixel_counts,
)
from skyvln_eval.sim.camera import render_views
from skyvln_eval.worlds.tile import WorldTile


@dataclass(frozen=True)
class Capture:
    """One image the agent captured: the heading and pitch it asked for, the RGB it got and
    the camera's pose (the harness logs these; the agent never sees this record)."""

    heading_deg: float
    pitch_deg: float
    rgb: NDArray[np.uint8]
    pose: CameraPose


class SimulatedSensors:
    """RGB (always), depth and the semantic camera over ``world``, at one drone position.

    ``captures`` keeps every image handed out from here, in order, for the run log.
    """

    def __init__(
        self, world: WorldTile, x_m: float, y_m: float, z_m: float, config: SensorConfig
    ) -> None:
        self._world = world
        self._position = (x_m, y_m, z_m)
        self._config = config
        self._camera = config.camera()
        self._key = next(_KEYS)
        _LIVE[self._key] = self
        self.captures: list[Capture] = []

    def handle(self) -> SensorHandle:
        """What the agent is given: captures from here, and nothing else."""
        return SensorHandle(self._key, self._config.kinds)

    @property
    def kinds(self) -> frozenset[SensorKind]:
        return self._config.kinds

    def capture(self, heading_deg: float, pitch_deg: float) -> CameraImages:
        return self.capture_many([(heading_deg, pitch_deg)])[0]

    def capture_many(self, views: Sequence[tuple[float, float]]) -> list[CameraImages]:
        x, y, z = self._position
        poses = [CameraPose(x, y, z, compass_to_enu_yaw_rad(h), p) for h, p in views]
        rendered = RECENT_RENDERS.render(self._world, poses, self._camera)
        images = [_read_only(self._restrict(i)) for i in rendered]
        self.captures += [
            Capture(float(h), float(p), i.rgb, pose)
            for (h, p), i, pose in zip(views, images, poses, strict=True)
        ]
        return images

    def _restrict(self, images: CameraImages) -> CameraImages:
        """Only the channels of the sensors the drone carries."""
        kinds = self._config.kinds
        if "semantic" in kinds and images.instance is not None:
            images = self._numbered_in_capture(images, images.instance)
        else:
            images = replace(images, semantic=None, instance=None, instance_categories={})
        if "depth" not in kinds:
            images = replace(images, depth_m=None)
        return images

    def _numbered_in_capture(
        self, images: CameraImages, instance: NDArray[np.uint16]
    ) -> CameraImages:
        """The capture's instances numbered 1, 2, ... in the order of the world's ids, with
        their categories: a segmentation tells instances apart within an image, it does
        not know which landmark of the map each one is (the world's ids would: the same
        landmark under the same number in every view). The order kept keeps each
        instance's rank, so what a detector does with them is the same."""
        ids = instance_pixel_counts(instance)[0]
        ids = ids[ids > 0]
        lookup = np.zeros(int(instance.max()) + 1, dtype=np.uint16)
        lookup[ids] = np.arange(1, len(ids) + 1, dtype=np.uint16)
        categories = {
            number: self._world.landmark(int(i)).category
            for number, i in enumerate(ids.tolist(), start=1)
        }
        return replace(images, instance=lookup[instance], instance_categories=categories)


class RecentRenders:
    """The last few batches of views rendered in this process, by world, poses and camera.

    A drone often looks again from exactly where it looked before (an official step that
    was refused or only turned it back, a cancelled flight): those views are the same
    pixels (the renderer is a pure function of its inputs), so they are copied, not
    rendered again. Every capture gets arrays of its own, so what one agent does to its
    images cannot reach another capture. Safe for episode threads (one lock; rendering
    runs outside it).
    """

    def __init__(self, size: int = 4) -> None:
        self.size = size
        self.hits = 0
        self._batches: OrderedDict[
            tuple[WorldTile, tuple[CameraPose, ...], CameraConfig], list[CameraImages]
        ] = OrderedDict()
        self._lock = threading.Lock()

    def render(
        self, world: WorldTile, poses: Sequence[CameraPose], camera: CameraConfig
    ) -> list[CameraImages]:
        """``render_views(world, poses, camera)``, copied from a recent batch when it is one."""
        key = (world, tuple(poses), camera)
        with self._lock:
            batch = self._batches.get(key)
            if batch is not None:
                self._batches.move_to_end(key)
                self.hits += 1
        if batch is None:
            batch = render_views(world, poses, camera)
            with self._lock:
                self._batches[key] = batch
                while len(self._batches) > self.size:
                    self._batches.popitem(last=False)
        return [_copied(images) for images in batch]

    def clear(self) -> None:
        with self._lock:
            self._batches.clear()
            self.hits = 0


def _read_only(images: CameraImages) -> CameraImages:
    """``images`` with its arrays made read-only: the run log keeps the agent's RGB views,
    so an agent that painted on them would change what is recorded of its flight."""
    for array in (images.rgb, images.depth_m, images.semantic, images.instance):
        if array is not None:
            array.flags.writeable = False
    return images


def _copied(images: CameraImages) -> CameraImages:
    return replace(
        images,
        rgb=images.rgb.copy(),
        depth_m=None if images.depth_m is None else images.depth_m.copy(),
        semantic=None if images.semantic is None else images.semantic.copy(),
        instance=None if images.instance is None else images.instance.copy(),
    )


#: This process's recent renders (about 10 MB: four decisions' views).
RECENT_RENDERS = RecentRenders()

_KEYS = itertools.count(1)
#: Simulators of the steps under way, by key; an entry goes when its simulator does.
_LIVE: weakref.WeakValueDictionary[int, SimulatedSensors] = weakref.WeakValueDictionary()


@dataclass(frozen=True)
class SensorHandle:
    """An agent's handle on the drone's sensors for one step.

    It implements :class:`~skyvln_eval.sensing.Sensors` and holds a key and the sensor
    kinds, nothing else; a capture after its step is over is an error.
    """

    key: int
    kinds: frozenset[SensorKind]

    def _sensors(self) -> SimulatedSensors:
        sensors = _LIVE.get(self.key)
        if sensors is None:
            raise PerceptionError("these sensors belong to a step that is over: capture now")
        return sensors

    def capture(self, heading_deg: float, pitch_deg: float) -> CameraImages:
        return self._sensors().capture(heading_deg, pitch_deg)

    def capture_many(self, views: Sequence[tuple[float, float]]) -> list[CameraImages]:
        return self._sensors().capture_many(views)
