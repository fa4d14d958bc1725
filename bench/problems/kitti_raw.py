"""``problem=kitti_raw``: any synced KITTI raw drive (``path=.../<date>_drive_<nnnn>_sync``):
OXTS truth and IMU, the calib files' reference calibration, grayscale image_00 tracked once by
the KLT front end (avio/frontend/klt.py) and cached under ``cache_dir``. The truth calibration is
unknown (no calibration errors are reported)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from avio.calibration import Calibration
from avio.errors import AvioError
from bench.problems.base import ProblemError, register
from bench.problems.vio import Drives, VioParams, VioProblem, _tuples


@dataclass(frozen=True)
class KittiRawParams(VioParams):
    """path: the drive folder (required); calib_dir: null = the drive folder's parent (the KITTI
    layout); cache_dir: the front end's cache; frontend: avio.frontend.klt.FrontendConfig settings."""

    path: str | None = None
    calib_dir: str | None = None
    cache_dir: str = ".cache/frontend"
    frontend: dict | None = field(default_factory=lambda: {"max_features": 30})

    def validate(self) -> None:
        from avio.frontend.klt import FrontendConfig

        if not self.path:
            raise ProblemError("kitti_raw needs problem.params.path=.../<date>_drive_<nnnn>_sync")
        try:
            FrontendConfig(**_tuples(self.frontend))
        except TypeError as err:
            raise ProblemError(f"frontend: {err}") from None
        super().validate()

    def _calib_dir(self) -> Path:
        return Path(self.calib_dir) if self.calib_dir else Path(self.path).parent

    def _reference(self) -> tuple[Calibration, tuple[int, int]]:
        from avio.datasets.kitti_raw import reference_calibration

        try:
            return reference_calibration(self._calib_dir())
        except AvioError as err:  # KittiRawError, or a CalibrationError of the file's values
            raise ProblemError(str(err)) from None

    def nominal_for_checks(self) -> Calibration:
        return self._reference()[0]

    def image_size_for_checks(self) -> tuple[int, int]:
        return self._reference()[1]

    def check_data(self) -> None:
        from avio.datasets.oxts import read_oxts_packets, read_timestamps

        drive = Path(self.path)
        if not (drive / "oxts" / "data").is_dir():
            raise ProblemError(f"{drive}: not a KITTI raw drive folder (no oxts/data); point problem.params.path at "
                               "a synced drive, .../<date>/<date>_drive_<nnnn>_sync (`python -m bench.data kitti_raw`)")
        try:
            packets = read_oxts_packets(drive / "oxts" / "data")
            stamps = read_timestamps(drive / "oxts" / "timestamps.txt")[0]
        except (AvioError, OSError) as err:  # OxtsError, KittiRawError
            raise ProblemError(str(err)) from None
        if len(stamps) != len(packets):
            raise ProblemError(f"{drive / 'oxts'}: {len(stamps)} timestamps for {len(packets)} OXTS packets")
        images = sorted((drive / "image_00" / "data").glob("*.png"))
        if len(images) != len(packets):
            raise ProblemError(f"{drive / 'image_00' / 'data'}: {len(images)} images for {len(packets)} OXTS "
                               "packets (the front end needs one grayscale image per packet)")

    def build(self) -> Drives:
        from avio.datasets.kitti_raw import load_kitti_raw
        from avio.frontend.cache import sequence_with_tracks
        from avio.frontend.klt import FrontendConfig

        sequence = load_kitti_raw(self.path, self.calib_dir)
        sequence = sequence_with_tracks(sequence, FrontendConfig(**_tuples(self.frontend)), self.cache_dir)
        return Drives((sequence,), None)


@register("kitti_raw")
class KittiRaw(VioProblem):
    """A synced KITTI raw drive through the KLT front end (module docstring)."""

    Params = KittiRawParams
    name = "kitti_raw"
