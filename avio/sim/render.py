"""Grayscale images of the landmark world as the simulated camera sees it (for the KLT front end).

Each landmark is a bright Gaussian blob, integrated over each pixel's area (pixel centres at
integer coordinates, as in OpenCV), so the blob's centroid is its true projection; its width
shrinks with depth (``sigma = blob_size_m * fx / depth``, clipped) and its brightness is fixed
per landmark so a tracker sees a stable appearance. A concentric, wider and dimmer halo
(``halo_scale`` x sigma, ``halo_ratio`` x brightness) gives the coarse levels of a KLT pyramid
something to track, so motions of tens of pixels converge; being concentric it leaves the
centroid unchanged. Blobs add onto a flat background with per-frame Gaussian noise; the result
is rounded to uint8. Occlusion is not modelled.
The true projections are saved next to the images (``projections.npz``) so tracking error can
be measured (load_projections).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
from scipy.special import ndtr

from avio.calibration import Calibration
from avio.errors import AvioError
from avio.sequence import GroundTruth
from avio.sim.camera import Observations, project_landmarks
from avio.sim.trajectory import TrajectoryFn

RENDER_VERSION = 1  # bump when the image model changes, so cached renders are not reused
PROJECTIONS_FILE = "projections.npz"
_DONE_FILE = "render_complete.json"


class RenderError(AvioError):
    """Bad render input or an unreadable render folder; the message names the file or argument."""


def render_image(
    uv_px: np.ndarray,
    sigma_px: np.ndarray,
    amplitude_dn: np.ndarray,
    image_size_px: tuple[int, int],
    background_dn: float | np.ndarray = 0.0,
) -> np.ndarray:
    """(height, width) float image: pixel-integrated Gaussian blobs on a background.

    uv_px: (n, 2) blob centres, pixels; sigma_px: (n,) widths; amplitude_dn: (n,) peak heights
    (grey levels, for a wide blob). A blob's pixel values are ``amplitude * 2 pi sigma^2`` times
    the Gaussian's mass inside the pixel, cut at 4 sigma.
    """
    width, height = image_size_px
    image = np.broadcast_to(np.asarray(background_dn, float), (height, width)).astype(float).ravel()
    uv_px = np.asarray(uv_px, float).reshape(-1, 2)
    if len(uv_px) == 0:
        return image.reshape(height, width)
    sigma = np.asarray(sigma_px, float)
    r = int(np.ceil(4 * sigma.max()))
    offsets = np.arange(-r, r + 1)

    def mass_1d(centre):
        pix = np.round(centre)[:, None] + offsets  # (n, w) pixel indices around each centre
        lo = (pix - 0.5 - centre[:, None]) / sigma[:, None]
        return pix.astype(np.int64), ndtr(lo + 1.0 / sigma[:, None]) - ndtr(lo)

    cols, gx = mass_1d(uv_px[:, 0])
    rows, gy = mass_1d(uv_px[:, 1])
    weight = (np.asarray(amplitude_dn, float) * 2 * np.pi * sigma**2)[:, None, None] * gy[:, :, None] * gx[:, None, :]
    rr = np.broadcast_to(rows[:, :, None], weight.shape)
    cc = np.broadcast_to(cols[:, None, :], weight.shape)
    inside = (rr >= 0) & (rr < height) & (cc >= 0) & (cc < width)
    # bincount accumulates overlapping blobs; faster than np.add.at
    image += np.bincount((rr * width + cc)[inside], weights=weight[inside], minlength=height * width)
    return image.reshape(height, width)


def blob_sigma_px(depth_m: np.ndarray, fx_px: float, blob_size_m: float,
                  sigma_range_px: tuple[float, float]) -> np.ndarray:
    """(m,) blob width in pixels of a landmark of size blob_size_m at depth_m (clipped)."""
    return np.clip(blob_size_m * fx_px / np.asarray(depth_m, float), *sigma_range_px)


def render_frames(
    truth: GroundTruth | TrajectoryFn,
    frame_t_s: np.ndarray,
    calibration: Calibration,
    landmarks_world: np.ndarray,
    image_size_px: tuple[int, int],
    out_dir: str | Path,
    rng: np.random.Generator,
    *,
    blob_size_m: float = 0.15,
    sigma_range_px: tuple[float, float] = (1.0, 3.0),
    amplitude_range_dn: tuple[float, float] = (90.0, 180.0),
    background_dn: float = 40.0,
    noise_dn: float = 2.0,
    max_depth_m: float = 80.0,
    halo_scale: float = 4.0,
    halo_ratio: float = 0.3,
) -> tuple[str, ...]:
    """Render one PNG per frame (``frame_000000.png`` ...) into out_dir; return their paths.

    The camera of each frame is the truth pose composed with ``calibration`` (batch of 1,
    avio.sim.camera.camera_poses, time offset included). Saves the true projections
    (``projections.npz``: frame_index, landmark_id, uv_px, depth_m, sigma_px, amplitude_dn). A
    folder already holding a complete render (marker file written last) is reused as is.
    Widths in pixels, brightness in grey levels (DN).
    """
    out_dir = Path(out_dir)
    n = len(frame_t_s)
    paths = tuple(str(out_dir / f"frame_{k:06d}.png") for k in range(n))
    done = out_dir / _DONE_FILE
    if done.exists() and json.loads(done.read_text()).get("n_frames") == n and all(Path(p).exists() for p in paths):
        return paths
    out_dir.mkdir(parents=True, exist_ok=True)
    obs = project_landmarks(truth, frame_t_s, calibration, landmarks_world, image_size_px, 1.0, max_depth_m)
    amplitude = rng.uniform(*amplitude_range_dn, len(landmarks_world))
    sigma = blob_sigma_px(obs.depth_m, calibration.fx_px[0], blob_size_m, sigma_range_px)
    width, height = image_size_px
    bounds = np.searchsorted(obs.frame_index, np.arange(n + 1))  # observations are frame-ordered
    for k in range(n):  # one image file per frame
        sl = slice(bounds[k], bounds[k + 1])
        background = background_dn + noise_dn * rng.standard_normal((height, width))
        amp = amplitude[obs.landmark_id[sl]]
        # A wide, dim halo around each blob survives the KLT pyramid's down-sampling (coarse levels
        # see the large motions); it is concentric, so the centroid stays the true projection.
        image = render_image(obs.uv_px[sl], sigma[sl], amp, image_size_px, background)
        if halo_ratio > 0:  # a separate call keeps the cores' windows small
            image += render_image(obs.uv_px[sl], halo_scale * sigma[sl], halo_ratio * amp, image_size_px)
        if not cv2.imwrite(paths[k], np.clip(np.round(image), 0, 255).astype(np.uint8)):
            raise RenderError(f"avio.render: could not write {paths[k]}")
    np.savez(
        out_dir / PROJECTIONS_FILE, frame_index=obs.frame_index, landmark_id=obs.landmark_id,
        uv_px=obs.uv_px, depth_m=obs.depth_m, sigma_px=sigma, amplitude_dn=amplitude[obs.landmark_id],
    )
    done.write_text(json.dumps({"n_frames": n}))
    return paths


def load_projections(out_dir: str | Path) -> tuple[Observations, np.ndarray]:
    """The true projections saved by render_frames: (Observations, sigma_px (m,))."""
    path = Path(out_dir) / PROJECTIONS_FILE
    try:
        with np.load(path, allow_pickle=False) as z:
            obs = Observations(z["frame_index"], z["landmark_id"], z["uv_px"], z["depth_m"])
            return obs, z["sigma_px"]
    except (OSError, KeyError, ValueError) as err:
        raise RenderError(f"avio.render: cannot read true projections from {path}: {err}") from err
