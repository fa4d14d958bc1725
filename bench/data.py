"""``python -m bench.data [PROBLEM ...] [--check [DIR]]``: the data each VIO problem reads.

Without ``--check``: for each registered VIO problem, the files it reads (relative to the data
folder), their sizes, what each is and where the public originals come from. Needs no data.

``--check [DIR]``: checks the folder (default: the one the problems read: ``$AVIO_DATA``, else
``../shared/data`` beside a source checkout, else the user data folder; see
avio/datasets/paths.py): every file present, of the recorded size and SHA-256 (whole files: the
data is ~18 MB and hashes in well under a second; a file of the wrong size is not hashed).
Exit 0 when every file of every problem asked for matches; 2 with one message per problem that
does not, or for an unknown problem name.

The sizes and hashes are those of the files in ``../shared/data`` the results were made with;
docs/guide/data.md says how to get them and the layout.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from dataclasses import dataclass
from pathlib import Path

KITTI_LICENCE = "CC BY-NC-SA 3.0 (Geiger, Lenz, Stiller, Urtasun, IJRR 2013); non-commercial use"
EUROC_LICENCE = ("the EuRoC MAV dataset's terms (ASL, ETH Zurich; cite Burri et al., IJRR 2016); "
                 "the feature file: GTSAM's examples (BSD)")


@dataclass(frozen=True)
class DataFile:
    """A file (or, when ``path`` has a ``*``, the files matching it) under the data folder.

    size: bytes (a group: the sum); sha256: of the bytes (a group: of the files' bytes
    concatenated in name order); count: how many files a group holds."""

    path: str
    size: int
    sha256: str
    what: str
    count: int = 1


@dataclass(frozen=True)
class ProblemData:
    """What a problem reads: ``files`` under the data folder, where they come from, their licence."""

    summary: str
    origin: str = ""
    licence: str = ""
    files: tuple[DataFile, ...] = ()


_K = "kitti00/"
_KITTI00 = (
    DataFile(_K + "KITTI_00_gt.txt", 728871, "90791a4113df979b149fa9e1104e960ea59f525a8318a202dbb6aec1a3d88793",
             "4541 ground-truth poses T_w_cam0 (KITTI odometry poses/00.txt)"),
    DataFile(_K + "KITTI_00_gt_times.txt", 59033, "99a2899466cdc28dd292b4856d214a8b0aab035b91b02bb6afcb4ff363e7d421",
             "4541 frame times (KITTI odometry sequences/00/times.txt)"),
    DataFile(_K + "KittiEquivBiasedImu.txt", 6648928,
             "90264418a69979eccd6d84eb69560225dff544bf6affe353ea37bb70d4ecf38a",
             "the drive's real 100 Hz OXTS IMU (GTSAM examples/Data)"),
)
_TRACKS = DataFile(_K + "VO_stereo_factors00.txt", 5150539,
                   "d05d5e9948676c702c60ce7ed5d7db7c4cbfb4dd2b3f2987e8eacb00000b2e87",
                   "real stereo feature tracks of frames 0-153 (GTSAM examples/Data)")
_KITTI00_ORIGIN = ("KITTI odometry sequence 00 = raw drive 2011_10_03_drive_0027: ground-truth poses and times from "
                   "https://www.cvlibs.net/datasets/kitti/eval_odometry.php (data_odometry_poses.zip, "
                   "data_odometry_calib.zip); the IMU and the tracks as shipped in GTSAM's examples/Data "
                   "(https://github.com/borglab/gtsam, BSD), made from the KITTI raw drive")

_R = "kitti_raw_2011_09_26_drive_0001/"
_D = _R + "2011_09_26_drive_0001_sync/"
_KITTI_RAW = (
    DataFile(_R + "calib_cam_to_cam.txt", 3001, "edc1eae281cb95e41798a98dcc545521449527145477ff852dbf3a4ec48c643c",
             "the date's camera calibration"),
    DataFile(_R + "calib_imu_to_velo.txt", 200, "07ca9ed33a2d968fc6358617d2c70e048b6f8e0f6ee5b73ae963afc1b19456ce",
             "IMU to Velodyne"),
    DataFile(_R + "calib_velo_to_cam.txt", 271, "9dc0c3e92dfceceb9500caa2c9488261a52640e43c3f7c3045ca1ed7927e7266",
             "Velodyne to camera"),
    DataFile(_D + "oxts/data/*.txt", 46839, "377be77c5045f48ae75d3a33d4354495ba6f6b2a1735e4ee2e48a1472f9f14da",
             "108 synced OXTS packets", count=108),
    DataFile(_D + "oxts/timestamps.txt", 3240, "87a07546f54369662eb6c725b8c136215ca5d7c66a30689e64f760587748cf06",
             "OXTS timestamps"),
    DataFile(_D + "image_00/timestamps.txt", 180, "6cda5e421962b2a905da5b66092e35cee7a873c7982f1ca642238958bb98b0ca",
             "image_00 timestamps (truncated in the sample)"),
)

_E = "euroc_v1_01/"
_EUROC = (
    DataFile(_E + "eqvio_processed_30s.csv", 2665606,
             "3b62cc8093e2cbb081460abfffba663a61a5a9702a382acc3a583c5d056e27af",
             "first 30 s: 200 Hz IMU and undistorted feature tracks (eqvio-processed; GTSAM 4.3.0 gtsam/Data)"),
    DataFile(_E + "V1_01_easy_groundtruth.csv", 505731,
             "16543952bf69f3fb886008a26cc21d3c552deca8fa06087f0bc329c09d7fcbe3",
             "ground-truth state, state_groundtruth_estimate0 (OpenVINS ov_data/euroc_mav/V1_01_easy.csv)"),
    DataFile(_E + "kalibr_imucam_chain.yaml", 1226,
             "b9e11b7bcda102f7c8c384c97318d67f3916b58942f9073722f83c22bd7073f7",
             "the Kalibr camera-IMU calibration (OpenVINS config/euroc_mav/)"),
    DataFile(_E + "kalibr_imu_chain.yaml", 1320, "408ea8b60b5f9e7c8251e6d302f04c0675bfefdd31229bb1afd139bc8f4a0287",
             "the IMU noise densities (OpenVINS config/euroc_mav/)"),
)

#: Every registered VIO problem, by its registered name (tests/bench/test_data.py keeps it complete).
PROBLEM_DATA: dict[str, ProblemData] = {
    "synthetic": ProblemData("simulated drive and camera: needs no data"),
    "kitti00": ProblemData("KITTI 00 real IMU and ground truth, simulated camera", _KITTI00_ORIGIN, KITTI_LICENCE,
                           _KITTI00),
    "kitti00_tracks": ProblemData("KITTI 00 frames 15-153, all real: the IMU, ground truth and real tracks",
                                  _KITTI00_ORIGIN, KITTI_LICENCE, (*_KITTI00, _TRACKS)),
    "kitti_raw": ProblemData(
        "any synced KITTI raw drive, named by problem.params.path (its images under image_00/data/ are needed "
        "to run); the files below are the sample drive the tests read (calib and OXTS, no images)",
        "KITTI raw https://www.cvlibs.net/datasets/kitti/raw_data.php: <date>_drive_<nnnn> [synced+rectified data] "
        "and <date>_calib.zip, unzipped as <date>/<date>_drive_<nnnn>_sync/ beside the calib files",
        KITTI_LICENCE, _KITTI_RAW),
    "euroc": ProblemData(
        "EuRoC MAV Vicon Room 1 01 (easy), all real",
        "EuRoC MAV https://projects.asl.ethz.ch/datasets/doku.php?id=kmavvisualinertialdatasets (V1_01_easy); "
        "the 30 s feature file from the GTSAM 4.3.0 wheel's gtsam/Data (BSD), the ground truth and Kalibr files "
        "as in OpenVINS (https://github.com/rpng/open_vins)",
        EUROC_LICENCE, _EUROC),
}


def sha256_of(paths: list[Path]) -> str:
    """SHA-256 of the files' bytes, concatenated in the order given."""
    digest = hashlib.sha256()
    for path in paths:
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


def check_file(root: Path, entry: DataFile) -> str | None:
    """None when ``entry`` is present under ``root`` with its size and hash, else what is wrong."""
    if "*" in entry.path:
        parent, pattern = entry.path.rsplit("/", 1)
        paths = sorted(p for p in (root / parent).glob(pattern) if p.is_file())
        if len(paths) != entry.count:
            return f"{root / entry.path}: {len(paths)} files, expected {entry.count}"
    else:
        paths = [root / entry.path]
        if not paths[0].is_file():
            return f"{paths[0]}: missing"
    size = sum(p.stat().st_size for p in paths)
    if size != entry.size:
        return f"{root / entry.path}: {size} bytes, expected {entry.size}"
    if sha256_of(paths) != entry.sha256:
        return f"{root / entry.path}: SHA-256 differs from the recorded one (another version of the file?)"
    return None


def check(root: Path, names: list[str]) -> list[str]:
    """One message per problem of ``names`` whose files under ``root`` do not all match; [] when all do."""
    messages = []
    for name in names:
        if PROBLEM_DATA[name].files and not root.is_dir():
            messages.append(f"{name}: data folder {root} not found (pass DIR, or set AVIO_DATA; docs/guide/data.md)")
            continue
        problems = [msg for entry in PROBLEM_DATA[name].files if (msg := check_file(root, entry))]
        if problems:
            messages.append(f"{name}: {len(problems)} of {len(PROBLEM_DATA[name].files)} files wrong: "
                            + "; ".join(problems))
    return messages


def listing(names: list[str], root: Path) -> str:
    """The files each problem reads, their origin, licence and layout under ``root``."""
    lines = [f"Data folder: {root}  (AVIO_DATA=..., or problem.params.data_dir=... per problem)", ""]
    width = max((len(e.path) for n in names for e in PROBLEM_DATA[n].files), default=0)
    for name in names:
        data = PROBLEM_DATA[name]
        lines.append(f"{name}: {data.summary}")
        if data.origin:
            lines += [f"  from:    {data.origin}", f"  licence: {data.licence}"]
        lines += [f"  {e.path:<{width}} {e.size:>10,} B  {e.what}" for e in data.files]
        lines.append("")
    lines.append("Check a folder: python -m bench.data --check [DIR]   (docs/guide/data.md)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from bench.problems.vio import default_data_dir

    parser = argparse.ArgumentParser(prog="python -m bench.data", epilog="docs/guide/data.md",
                                     description="The files each VIO problem reads and where they come from; "
                                                 "--check verifies them (size and SHA-256).")
    parser.add_argument("problems", nargs="*", metavar="PROBLEM",
                        help=f"problems to list or check (default: all): {', '.join(PROBLEM_DATA)}")
    parser.add_argument("--check", nargs="?", const="", default=None, metavar="DIR",
                        help="check the files under DIR (default: the data folder the problems read)")
    args = parser.parse_args(argv)
    if args.check in PROBLEM_DATA and not Path(args.check).is_dir():  # `--check kitti00`: a problem, not DIR
        args.problems, args.check = [args.check, *args.problems], ""
    unknown = [n for n in args.problems if n not in PROBLEM_DATA]
    if unknown:
        print(f"bench.data: unknown problem(s) {unknown}; valid: {', '.join(PROBLEM_DATA)}", file=sys.stderr)
        return 2
    names = args.problems or list(PROBLEM_DATA)
    root = default_data_dir(args.check or None)
    if args.check is None:
        print(listing(names, root))
        return 0
    messages = check(root, names)
    for message in messages:
        print(message, file=sys.stderr)
    for name in names:
        if not any(m.startswith(f"{name}: ") for m in messages):
            print(f"{name}: ok ({len(PROBLEM_DATA[name].files)} files)" if PROBLEM_DATA[name].files
                  else f"{name}: ok (needs no data)")
    return 2 if messages else 0


if __name__ == "__main__":
    raise SystemExit(main())
