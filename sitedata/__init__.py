"""Site data: the simulator's inputs for the Gusev and Meridiani campaigns.

* :mod:`sitedata.sites`    landing-site files: appearance classes, ellipse fractions, sun, camera, trajectory set;
* :mod:`sitedata.edl`      EDL descent profiles: generator, parameter files, trajectory files;
* :mod:`sitedata.terrain`  terrain of each appearance class: synthetic MOC-like strips, real orbital images.

The data files (site and camera TOMLs, trajectory sets) sit beside the code in this directory.
"""
from pathlib import Path

SITEDATA_DIR = Path(__file__).resolve().parent
