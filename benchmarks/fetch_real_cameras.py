#!/usr/bin/env python3
"""Extract the real-camera test photos that are NOT vendored in this repo.

The photos listed in benchmarks/data/real_cameras.csv come from two public
GitHub repositories.  Only the MyntEye pair (BSD-2-Clause) is copied into
benchmarks/data/real_cameras/; the rest is GPL (OCamCalib sample images) or of
unstated licence (EuRoC frames), so this script pulls them out of a local git
copy of the source repository instead of us redistributing them.

Usage:
    python benchmarks/fetch_real_cameras.py --ocamcalib GITDIR --kimera GITDIR \
        [--out benchmarks/data/real_cameras]

GITDIR is either a normal clone (its .git is found) or a bare git directory of

    urbste/ImprovedOcamCalib   (needs commit 7d9ed056b0fd9b423f677ad8f89101764adb662b
                                in its history; a full clone has it)
    MIT-SPARK/Kimera-VIO       (commit ce8c59b7b273ab5ac29db7e5572e1623760e19c7 or any
                                later one that still has tests/data/MicroEurocDataset)

Either option may be left out; the cameras of the missing source are skipped
with a message saying what to fetch.  Files are written under
OUT/<camera name>/ with their original bytes (no re-encoding, no resizing).
"""
import argparse
import os
import subprocess
import sys

OCAM_COMMIT = "7d9ed056b0fd9b423f677ad8f89101764adb662b"
OCAM_DIR = "OcamCalibUrban/Scaramuzza_OCamCalib_v3.0_win/Scaramuzza_OCamCalib_v3.0_win"
KIMERA_COMMIT = "ce8c59b7b273ab5ac29db7e5572e1623760e19c7"

# camera name -> list of (path in repo, file name to write)
OCAM_FILES = {
    "ocam_fisheye190": [(f"{OCAM_DIR}/Fisheye190deg{i}.jpg", f"Fisheye190deg{i}.jpg") for i in range(1, 9)],
    "ocam_fisheye1": [(f"{OCAM_DIR}/Fisheye1_{i}.jpg", f"Fisheye1_{i}.jpg") for i in range(1, 16)],
    "ocam_fisheye2": [(f"{OCAM_DIR}/Fisheye2_{i}.jpg", f"Fisheye2_{i}.jpg") for i in range(1, 17)],
    "ocam_back": [(f"OcamCalibUrban/tests/imgBack{i}.jpg", f"imgBack{i}.jpg") for i in range(1, 12)]
    + [(f"{OCAM_DIR}/calib_results.txt", "calib_results.txt")],
    "ocam_ladybug": [(f"{OCAM_DIR}/Ladybug{i}.jpg", f"Ladybug{i}.jpg") for i in range(1, 10)],
}

KIMERA_EUROC_PREFIX = "tests/data/MicroEurocDataset/mav0"


def git_dir(path):
    """Return the git directory for a clone or a bare repository."""
    if os.path.isdir(os.path.join(path, ".git")):
        return os.path.join(path, ".git")
    if os.path.isfile(os.path.join(path, "HEAD")) and os.path.isdir(os.path.join(path, "objects")):
        return path
    raise SystemExit(f"{path}: not a git clone nor a bare git directory")


def git(gd, *args):
    return subprocess.run(["git", "--git-dir", gd, *args], check=True,
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE).stdout


def has_commit(gd, commit):
    r = subprocess.run(["git", "--git-dir", gd, "cat-file", "-e", commit + "^{commit}"],
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return r.returncode == 0


def write(gd, commit, path, dest):
    os.makedirs(os.path.dirname(dest), exist_ok=True)
    data = git(gd, "show", f"{commit}:{path}")
    with open(dest, "wb") as f:
        f.write(data)
    return len(data)


def extract_ocam(gd, out):
    if not has_commit(gd, OCAM_COMMIT):
        print(f"ocamcalib: commit {OCAM_COMMIT} is not in {gd}; fetch the full history of "
              "github.com/urbste/ImprovedOcamCalib (a plain clone has it)", file=sys.stderr)
        return 1
    n = 0
    for cam, files in OCAM_FILES.items():
        for path, name in files:
            n += write(gd, OCAM_COMMIT, path, os.path.join(out, cam, name))
    print(f"ocamcalib: {sum(len(v) for v in OCAM_FILES.values())} files, {n/1e6:.1f} MB")
    return 0


def extract_kimera(gd, out):
    commit = KIMERA_COMMIT if has_commit(gd, KIMERA_COMMIT) else "HEAD"
    try:
        names = git(gd, "ls-tree", "-r", "--name-only", commit, KIMERA_EUROC_PREFIX).decode().split()
    except subprocess.CalledProcessError:
        names = []
    if not names:
        print(f"kimera: {KIMERA_EUROC_PREFIX} not found in {gd}; fetch "
              "github.com/MIT-SPARK/Kimera-VIO", file=sys.stderr)
        return 1
    n = 0
    for p in names:
        rel = p[len(KIMERA_EUROC_PREFIX) + 1:]
        if rel.startswith(("cam0/", "cam1/")) or rel == "body.yaml":
            n += write(gd, commit, p, os.path.join(out, "euroc_mt9v034", rel))
    for s in ("left", "right"):
        for f in (f"{s}_frame0000.jpg", f"{s}_frame0001.jpg", f"{s}_frame0008.jpg"):
            n += write(gd, commit, f"tests/data/ForStereoTracker/{f}",
                       os.path.join(out, "euroc_mt9v034", "machine_hall", f))
    write(gd, commit, "tests/data/MicroEurocDataset/LICENSE.md",
          os.path.join(out, "euroc_mt9v034", "LICENSE.md"))
    print(f"kimera/euroc: {n/1e6:.1f} MB from {commit}")
    return 0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ocamcalib", help="git dir or clone of urbste/ImprovedOcamCalib")
    ap.add_argument("--kimera", help="git dir or clone of MIT-SPARK/Kimera-VIO")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "data", "real_cameras"))
    a = ap.parse_args()
    if not a.ocamcalib and not a.kimera:
        ap.print_help()
        print("\nNothing to do: give --ocamcalib and/or --kimera (see above for what to fetch).",
              file=sys.stderr)
        return 2
    rc = 0
    if a.ocamcalib:
        rc |= extract_ocam(git_dir(a.ocamcalib), a.out)
    else:
        print("ocamcalib: skipped (no --ocamcalib); cameras ocam_* need github.com/urbste/ImprovedOcamCalib",
              file=sys.stderr)
    if a.kimera:
        rc |= extract_kimera(git_dir(a.kimera), a.out)
    else:
        print("kimera: skipped (no --kimera); camera euroc_mt9v034 needs github.com/MIT-SPARK/Kimera-VIO",
              file=sys.stderr)
    return rc


if __name__ == "__main__":
    sys.exit(main())
