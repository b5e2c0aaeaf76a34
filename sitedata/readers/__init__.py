"""Readers for real orbital images used as terrain.

Formats: PDS3 ``.IMG`` (attached or detached label; MOC NA, HiRISE EDR, HRSC, THEMIS qubes),
ISIS3 ``.cub`` (tiled or band-sequential), VICAR, MSSS DDD, PNG, TIFF and GeoTIFF. Labels are
parsed by hand (:mod:`.pvl`); PNG/TIFF decoding uses Pillow. Every reader returns an
:class:`OrbitalImage`; every failure is a one-line :class:`ReaderError` naming the file and the
keyword or format at fault. A side-car TOML (:mod:`.sidecar`) supplies what a file lacks, and
:func:`load_terrain` turns file + side-car into a :class:`simulator.scene.terrain.Terrain`.
"""
from .image import OrbitalImage, ReaderError
from .isis3 import read_isis3
from .pds3 import read_pds3
from .raster import read_raster
from .sidecar import CropWindow, Sidecar, apply_sidecar, read_sidecar
from .terrain_file import detect_format, load_orbital_image, load_terrain, read_image
from .vicar import read_ddd, read_vicar

__all__ = [
    "OrbitalImage", "ReaderError", "Sidecar", "CropWindow", "read_image", "read_pds3", "read_isis3",
    "read_vicar", "read_ddd", "read_raster", "read_sidecar", "apply_sidecar", "load_orbital_image",
    "load_terrain", "detect_format",
]
