"""Readers for real orbital images used as terrain.

Formats: PDS3 ``.IMG`` (attached or detached label; MOC NA, HiRISE EDR, HRSC, THEMIS qubes),
ISIS3 ``.cub`` (tiled or band-sequential), VICAR, MSSS DDD, PNG, TIFF and GeoTIFF. Labels are
parsed by hand (:mod:`.pvl`); PNG/TIFF decoding uses Pillow. Every reader returns an
:class:`OrbitalImage`; every failure is a one-line :class:`ReaderError` naming the file and the
keyword or format at fault. A side-car TOML (:mod:`.sidecar`) supplies what a file lacks;
:func:`sitedata.terrain.real_terrain.load_terrain` turns file + side-car into a simulator terrain.
"""
from file_formats.planetary.image import OrbitalImage, ReaderError
from file_formats.planetary.isis3 import read_isis3
from file_formats.planetary.orbital_file import detect_format, load_orbital_image, read_image
from file_formats.planetary.pds3 import read_pds3
from file_formats.planetary.raster import read_raster
from file_formats.planetary.sidecar import CropWindow, Sidecar, apply_sidecar, read_sidecar
from file_formats.planetary.vicar import read_ddd, read_vicar

__all__ = [
    "OrbitalImage", "ReaderError", "Sidecar", "CropWindow", "read_image", "read_pds3", "read_isis3",
    "read_vicar", "read_ddd", "read_raster", "read_sidecar", "apply_sidecar", "load_orbital_image",
    "detect_format",
]
