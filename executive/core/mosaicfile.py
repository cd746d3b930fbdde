"""The ceiling mosaic file (issue 17, seed 002 §2.2): what a mapping run learnt, on disk.

A mosaic is the set of ceiling landmarks (the paper's 2D models ``m_i``) with their
planar pose ``M_T_i`` in the mosaic frame M (= the airport frame A,
:mod:`behaviours.laws.ceiling_landmarks`), each with its keypoints (positions in the
landmark's frame, pixels) and their ORB descriptors, and the camera and ceiling height
they were learnt with: the ORB descriptors are not scale-invariant here (two pyramid
levels), so a mosaic is only good for the same lens at the same distance from the ceiling.

Format: a NumPy ``.npz`` archive (written with ``numpy.savez_compressed``, read with
``allow_pickle=False``: no object arrays, nothing executed) of

* ``meta``: a 0-d unicode array holding a JSON object: ``format``
  (``"walkaround-ceiling-mosaic"``), ``version`` (:data:`MOSAIC_VERSION`),
  ``ceiling_height`` (m above the floor), ``camera`` (``focal_px``, ``cu``, ``cv``,
  ``height`` = Z, the ceiling above the optical centre, m, ``robot_from_camera`` =
  [x, y, theta] of the law's camera frame in R), ``image_size`` [width, height] (px),
  ``config`` (the landmark tuning used, name -> number) and ``ids`` (the landmark ids);
* ``poses`` (N, 3) float64: ``M_T_i`` as (x, y, theta) in m and rad;
* ``counts`` (N,) int64: keypoints per landmark, at least 1;
* ``points`` (K, 2) float64 and ``descriptors`` (K, 32) uint8, K = sum(counts): the
  landmarks' keypoints one after the other in ``ids`` order;
* ``created_in`` (N,) int64 and ``origin_px`` (N, 2) float64: the mapping image a
  landmark was created in and its origin there (for checking against a ground truth).

:func:`read_mosaic` checks all of it and raises :class:`MosaicFormatError` with one
sentence naming the file and what is wrong (a truncated archive, a missing member, a
wrong shape or type, a non-finite number, a newer version); it reads at most
:data:`MAX_MOSAIC_BYTES` and refuses archives whose members would expand beyond
:data:`MAX_MOSAIC_BYTES` too. This module is in the core (numpy only) so that the mission
loader can check a mission's mosaic; :mod:`behaviours.laws.mosaic` turns it into the
localiser. Units: m, rad, pixels.
"""

from __future__ import annotations

import io
import json
import math
import zipfile
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

from executive.core.files import UnusableFileError, read_regular, write_atomic
from executive.core.frames import FloatArray, Pose2

__all__ = [
    "MAX_MOSAIC_BYTES",
    "MOSAIC_FORMAT",
    "MOSAIC_VERSION",
    "MosaicData",
    "MosaicFormatError",
    "read_mosaic",
    "write_mosaic",
]

MOSAIC_FORMAT = "walkaround-ceiling-mosaic"
MOSAIC_VERSION = 1
#: the largest mosaic file, and the largest its arrays may expand to (a 60 m x 40 m hangar
#: mapped with 640x480 images has a few thousand landmarks: a few MB)
MAX_MOSAIC_BYTES = 256 * 1024 * 1024
DESCRIPTOR_BYTES = 32
_MEMBERS = ("meta", "poses", "counts", "points", "descriptors", "created_in", "origin_px")


class MosaicFormatError(ValueError):
    """A mosaic file that cannot be used; the message names the file and the reason."""


@dataclass(frozen=True, slots=True, eq=False)
class MosaicData:
    """A mosaic as stored (module doc): the camera, the tuning and the landmark arrays."""

    ceiling_height: float
    focal_px: float
    cu: float
    cv: float
    camera_height: float
    robot_from_camera: Pose2
    image_size: tuple[int, int]
    config: Mapping[str, float | int]
    ids: tuple[str, ...]
    poses: FloatArray
    counts: NDArray[np.int64]
    points: FloatArray
    descriptors: NDArray[np.uint8]
    created_in: NDArray[np.int64]
    origin_px: FloatArray

    def __post_init__(self) -> None:
        _check(self, "<memory>")

    def __len__(self) -> int:
        return len(self.ids)

    def keypoints(self) -> list[tuple[FloatArray, NDArray[np.uint8]]]:
        """Each landmark's (points, descriptors), in ``ids`` order."""
        ends = np.cumsum(self.counts)
        starts = ends - self.counts
        return [
            (self.points[a:b], self.descriptors[a:b])
            for a, b in zip(starts.tolist(), ends.tolist(), strict=True)
        ]


def write_mosaic(path: Path | str, data: MosaicData) -> None:
    """Write ``data`` at ``path`` (atomically: the old file or the new, never a torn one)."""
    meta = {
        "format": MOSAIC_FORMAT,
        "version": MOSAIC_VERSION,
        "ceiling_height": data.ceiling_height,
        "camera": {
            "focal_px": data.focal_px,
            "cu": data.cu,
            "cv": data.cv,
            "height": data.camera_height,
            "robot_from_camera": [
                data.robot_from_camera.x,
                data.robot_from_camera.y,
                data.robot_from_camera.theta,
            ],
        },
        "image_size": list(data.image_size),
        "config": dict(data.config),
        "ids": list(data.ids),
    }
    buffer = io.BytesIO()
    np.savez_compressed(
        buffer,
        meta=np.array(json.dumps(meta, allow_nan=False)),
        poses=np.asarray(data.poses, dtype=np.float64),
        counts=np.asarray(data.counts, dtype=np.int64),
        points=np.asarray(data.points, dtype=np.float64),
        descriptors=np.asarray(data.descriptors, dtype=np.uint8),
        created_in=np.asarray(data.created_in, dtype=np.int64),
        origin_px=np.asarray(data.origin_px, dtype=np.float64),
    )
    write_atomic(Path(path), buffer.getvalue())


def read_mosaic(path: Path | str) -> MosaicData:
    """The mosaic at ``path``, fully checked; :class:`MosaicFormatError` otherwise."""
    name = str(path)
    try:
        raw = read_regular(path, MAX_MOSAIC_BYTES)
    except UnusableFileError as exc:
        raise MosaicFormatError(str(exc)) from None
    arrays = _arrays(raw, name)
    meta = _meta(arrays["meta"], name)
    camera = _mapping(meta, "camera", name)
    size = meta.get("image_size")
    if not (isinstance(size, list) and len(size) == 2 and all(_is_int(v) and v > 0 for v in size)):
        raise MosaicFormatError(f"{name}: image_size must be [width, height] in pixels")
    rfc = camera.get("robot_from_camera")
    if not (isinstance(rfc, list) and len(rfc) == 3 and all(_is_number(v) for v in rfc)):
        raise MosaicFormatError(f"{name}: camera.robot_from_camera must be [x, y, theta]")
    ids = meta.get("ids")
    if not (isinstance(ids, list) and all(isinstance(v, str) for v in ids)):
        raise MosaicFormatError(f"{name}: ids must be a list of strings")
    config = _mapping(meta, "config", name)
    if not all(_is_number(v) for v in config.values()):
        raise MosaicFormatError(f"{name}: config values must be numbers")
    values = {
        key: _number(source, key, name, label)
        for source, key, label in (
            (meta, "ceiling_height", "ceiling_height"),
            (camera, "focal_px", "camera.focal_px"),
            (camera, "cu", "camera.cu"),
            (camera, "cv", "camera.cv"),
            (camera, "height", "camera.height"),
        )
    }
    data = object.__new__(MosaicData)  # checked once below, with the file's name
    for field_name, value in (
        ("ceiling_height", values["ceiling_height"]),
        ("focal_px", values["focal_px"]),
        ("cu", values["cu"]),
        ("cv", values["cv"]),
        ("camera_height", values["height"]),
        ("robot_from_camera", Pose2(*(float(v) for v in rfc))),
        ("image_size", (int(size[0]), int(size[1]))),
        ("config", MappingProxyType(dict(config))),
        ("ids", tuple(ids)),
        *((member, arrays[member]) for member in _MEMBERS[1:]),
    ):
        object.__setattr__(data, field_name, value)
    _check(data, name)
    return data


def _arrays(raw: bytes, name: str) -> dict[str, np.ndarray]:
    try:
        with zipfile.ZipFile(io.BytesIO(raw)) as archive:
            infos = archive.infolist()
            expanded = sum(info.file_size for info in infos)
            if expanded > MAX_MOSAIC_BYTES:
                raise MosaicFormatError(
                    f"{name}: its arrays would expand to {expanded} bytes, more than the "
                    f"{MAX_MOSAIC_BYTES} allowed"
                )
            present = {info.filename.removesuffix(".npy") for info in infos}
            missing = [m for m in _MEMBERS if m not in present]
            if missing:
                raise MosaicFormatError(
                    f"{name}: not a ceiling mosaic: missing {', '.join(missing)}"
                )
            with np.load(io.BytesIO(raw), allow_pickle=False) as npz:
                return {m: npz[m] for m in _MEMBERS}
    except MosaicFormatError:
        raise
    except (zipfile.BadZipFile, zlib.error, EOFError, ValueError, OSError, KeyError) as exc:
        raise MosaicFormatError(
            f"{name}: not a readable ceiling mosaic (.npz archive; truncated or corrupt?): {exc}"
        ) from None


def _meta(array: np.ndarray, name: str) -> dict[str, object]:
    if array.shape != () or array.dtype.kind != "U":
        raise MosaicFormatError(f"{name}: meta must be a JSON text")
    try:
        meta = json.loads(str(array[()]))
    except ValueError as exc:
        raise MosaicFormatError(f"{name}: meta is not valid JSON: {exc}") from None
    if not isinstance(meta, dict):
        raise MosaicFormatError(f"{name}: meta must be a JSON object")
    if meta.get("format") != MOSAIC_FORMAT:
        raise MosaicFormatError(f"{name}: not a ceiling mosaic (format {meta.get('format')!r})")
    version = meta.get("version")
    if not _is_int(version):
        raise MosaicFormatError(f"{name}: version must be an integer")
    if version != MOSAIC_VERSION:
        newer = "newer than" if version > MOSAIC_VERSION else "older than"
        raise MosaicFormatError(
            f"{name}: mosaic version {version} is {newer} the version this walkaround reads "
            f"({MOSAIC_VERSION})"
        )
    return meta


def _mapping(meta: Mapping[str, object], key: str, name: str) -> dict[str, object]:
    value = meta.get(key)
    if not isinstance(value, dict):
        raise MosaicFormatError(f"{name}: {key} must be a JSON object")
    return value


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _number(source: Mapping[str, object], key: str, name: str, label: str) -> float:
    value = source.get(key)
    if not _is_number(value):
        raise MosaicFormatError(f"{name}: {label} must be a finite number, got {value!r}")
    assert isinstance(value, int | float)
    return float(value)


def _check(data: MosaicData, name: str) -> None:
    """Every consistency rule of the module doc; MosaicFormatError naming ``name``."""

    def fail(message: str) -> None:
        raise MosaicFormatError(f"{name}: {message}")

    if not (data.focal_px > 0.0 and data.camera_height > 0.0):
        fail("camera focal_px and height must be > 0")
    if not data.ceiling_height >= data.camera_height:
        fail("the ceiling_height is below the camera's distance to the ceiling")
    n = len(data.ids)
    if len(set(data.ids)) != n or not all(data.ids):
        fail("landmark ids must be unique and non-empty")
    shapes: tuple[tuple[str, np.ndarray, str, tuple[int, ...]], ...] = (
        ("poses", data.poses, "f", (n, 3)),
        ("counts", data.counts, "i", (n,)),
        ("created_in", data.created_in, "i", (n,)),
        ("origin_px", data.origin_px, "f", (n, 2)),
    )
    for label, array, kind, shape in shapes:
        if not isinstance(array, np.ndarray) or array.dtype.kind != kind or array.shape != shape:
            fail(f"{label} must be a {shape} array of {'floats' if kind == 'f' else 'integers'}")
    if n and int(data.counts.min()) < 1:
        fail("every landmark needs at least one keypoint (counts >= 1)")
    k = int(data.counts.sum())
    if not (
        isinstance(data.points, np.ndarray)
        and data.points.dtype.kind == "f"
        and data.points.shape == (k, 2)
    ):
        fail(f"points must be a ({k}, 2) array of floats (the sum of counts)")
    descriptors = data.descriptors
    if not (
        isinstance(descriptors, np.ndarray)
        and descriptors.dtype == np.uint8
        and descriptors.shape == (k, DESCRIPTOR_BYTES)
    ):
        fail(f"descriptors must be a ({k}, {DESCRIPTOR_BYTES}) array of uint8")
    if not (np.isfinite(data.poses).all() and np.isfinite(data.points).all()):
        fail("poses and points must be finite")
