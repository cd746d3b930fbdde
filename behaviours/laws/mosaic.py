"""A ceiling mosaic saved and loaded (issue 17, seed 002 §2.2).

:func:`save_mosaic` writes what a :class:`~behaviours.laws.ceiling_landmarks.CeilingMapper`
learnt (or the mosaic of a :class:`~behaviours.laws.ceiling_landmarks.CeilingLocaliser`):
every landmark's pose ``M_T_i`` in the mosaic frame, its keypoints and ORB descriptors,
the law's camera (f, principal point, Z, ``robot_from_camera``), the image size, the
ceiling's height above the floor and the :class:`LandmarkConfig` it was built with, in the
file format of :mod:`executive.core.mosaicfile` (an ``.npz`` with a versioned JSON header).
:func:`load_mosaic` reads it back as a localiser that localises exactly as the one in
memory did (same landmarks, same camera, same tuning: the same floating-point numbers,
so the same fixes). Errors: :class:`~executive.core.mosaicfile.MosaicFormatError` with
the file's name and the reason.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from behaviours.laws.ceiling import CeilingCamera
from behaviours.laws.ceiling_landmarks import (
    CeilingLocaliser,
    CeilingMapper,
    Landmark,
    LandmarkConfig,
)
from executive.core.frames import Pose2
from executive.core.mosaicfile import MosaicData, MosaicFormatError, read_mosaic, write_mosaic

__all__ = ["load_mosaic", "localiser_from", "mosaic_data", "save_mosaic"]


def mosaic_data(source: CeilingMapper | CeilingLocaliser, ceiling_height: float) -> MosaicData:
    """The stored form of a mapper's or localiser's mosaic; ``ceiling_height`` (m above
    the floor) is the ceiling the camera (``source.camera.height`` below it) looked at.
    A mapper's provisional landmarks are stored with their current (mean) pose."""
    camera = source.camera
    landmarks = list(source.landmarks.values())
    counts = np.array([len(lm.points) for lm in landmarks], dtype=np.int64)
    return MosaicData(
        ceiling_height=float(ceiling_height),
        focal_px=camera.focal_px,
        cu=camera.cu,
        cv=camera.cv,
        camera_height=camera.height,
        robot_from_camera=camera.robot_from_camera,
        image_size=(int(source.image_size[0]), int(source.image_size[1])),
        config=dataclasses.asdict(source.config),
        ids=tuple(lm.landmark_id for lm in landmarks),
        poses=np.array(
            [(lm.pose.x, lm.pose.y, lm.pose.theta) for lm in landmarks], dtype=np.float64
        ).reshape(-1, 3),
        counts=counts,
        points=np.concatenate([lm.points for lm in landmarks]).astype(np.float64)
        if landmarks
        else np.zeros((0, 2)),
        descriptors=np.concatenate([lm.descriptors for lm in landmarks]).astype(np.uint8)
        if landmarks
        else np.zeros((0, 32), dtype=np.uint8),
        created_in=np.array([lm.created_in for lm in landmarks], dtype=np.int64),
        origin_px=np.array([lm.origin_px for lm in landmarks], dtype=np.float64).reshape(-1, 2),
    )


def save_mosaic(
    path: Path | str, source: CeilingMapper | CeilingLocaliser, *, ceiling_height: float
) -> None:
    """Write ``source``'s mosaic at ``path`` (atomically); see :func:`mosaic_data`."""
    write_mosaic(path, mosaic_data(source, ceiling_height))


def load_mosaic(path: Path | str) -> CeilingLocaliser:
    """The localiser on the mosaic at ``path`` (:class:`MosaicFormatError` if unusable)."""
    return localiser_from(read_mosaic(path), path)


def localiser_from(data: MosaicData, path: Path | str = "<memory>") -> CeilingLocaliser:
    """The localiser on a stored mosaic (``path`` names it in errors)."""
    try:
        camera = CeilingCamera(
            data.focal_px, data.cu, data.cv, data.camera_height, data.robot_from_camera
        )
    except ValueError as exc:
        raise MosaicFormatError(f"{path}: camera: {exc}") from None
    landmarks = {}
    for i, (lid, (points, descriptors)) in enumerate(zip(data.ids, data.keypoints(), strict=True)):
        x, y, theta = (float(v) for v in data.poses[i])
        u, v = (float(c) for c in data.origin_px[i])
        landmarks[lid] = Landmark(
            lid,
            Pose2(x, y, theta),
            np.ascontiguousarray(points, dtype=np.float64),
            np.ascontiguousarray(descriptors, dtype=np.uint8),
            int(data.created_in[i]),
            (u, v),
        )
    return CeilingLocaliser(camera, landmarks, data.image_size, _config(data, path))


def _config(data: MosaicData, path: Path | str) -> LandmarkConfig:
    """The stored tuning as a :class:`LandmarkConfig`; unknown names and wrong types are
    refused (a number where an integer is expected would change the detector)."""
    defaults = LandmarkConfig()
    values: dict[str, float | int] = {}
    for name, value in data.config.items():
        if name not in LandmarkConfig.__dataclass_fields__:
            raise MosaicFormatError(f"{path}: config: unknown setting '{name}'")
        if isinstance(getattr(defaults, name), int) and not isinstance(value, int):
            raise MosaicFormatError(f"{path}: config: {name} must be an integer")
        values[name] = value
    return dataclasses.replace(defaults, **values)
