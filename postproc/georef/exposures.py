"""The frame camera's photos of a synchronised flight into the photo EO path: each photo the sync
timed with its number (`postproc.sync.photos`: status ok or board_time) gets its exterior
orientation (`photos.photo_eo`) and is written by `photoexports` into OUT/photos/. Photos
flagged by the sync (no pulse, ambiguous, no photo number) are left out and counted, never
given a time they do not have."""

from __future__ import annotations

from pathlib import Path
from typing import Final

import numpy as np

from postproc.georef.navigation import Trajectory
from postproc.georef.photoexports import write_odm_geo, write_photo_csv, write_photo_sidecars
from postproc.georef.photos import PhotoSigma, photo_eo
from postproc.sync import PhotoStatus, PhotoTimes
from sisa.core.framecamera import FrameCamera

PHOTO_DIR: Final = "photos"


def photo_label(number: int) -> str:
    """A photo's name, as the camera (and the emulator: photo_NNNNNN.bil) calls its image."""
    return f"photo_{number:06d}"


def write_photo_eo(out_dir: Path, photos: PhotoTimes, traj: Trajectory, camera: FrameCamera,
                   epsg: int | None, sigma: PhotoSigma | None = None) -> list[str]:
    """OUT/photos/{photos_eo.csv, geo.txt, sidecars/} of the timed photos; the warnings: photos
    not timed, a photo number seen twice (the counter wrapped: the later ones are left out),
    photos without a navigation pose."""
    sigma = sigma or PhotoSigma()
    usable = np.isin(photos.status, (PhotoStatus.OK, PhotoStatus.BOARD_TIME))
    numbers = photos.photo_number[usable]
    _, first = np.unique(numbers, return_index=True)
    keep = np.sort(first)
    notes = []
    named = int(np.count_nonzero(photos.photo_number >= 0))
    if named > usable.sum():
        notes.append(f"{named - int(usable.sum())} of {named} photos have no time (the sync "
                     "flagged them: photo_times.csv says why): no EO for them")
    loose = int(np.count_nonzero(photos.status == PhotoStatus.NO_PHOTO_NUMBER))
    if loose:
        notes.append(f"{loose} camera pulses have no photo number (a lost photo message, or a "
                     "pulse the camera never made): timed in photo_times.csv, no EO")
    if keep.size < numbers.size:
        notes.append(f"{numbers.size - keep.size} photos repeat an earlier photo number (the "
                     "camera's counter wrapped): only the first of each has an EO")
    if not keep.size:
        return [*notes, "no photo was timed: no photo EO written"]
    labels = [photo_label(int(n)) for n in numbers[keep]]
    eo = photo_eo(traj, labels, photos.t_gps_ns[usable][keep], camera.mounting, epsg=epsg)
    folder = Path(out_dir) / PHOTO_DIR
    folder.mkdir(parents=True, exist_ok=True)
    written = write_photo_csv(folder / "photos_eo.csv", eo, sigma)
    write_odm_geo(folder / "geo.txt", eo, sigma)
    write_photo_sidecars(folder / "sidecars", eo, sigma, camera)
    if written < keep.size:
        notes.append(f"{keep.size - written} of {keep.size} timed photos have no navigation "
                     "pose (outside the trajectory or in its gaps): no EO for them")
    return notes
