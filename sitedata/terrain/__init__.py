"""Terrain of each appearance class: synthetic MOC-NA-like strips (:mod:`.synthetic_terrain`), real
orbital images with their side-cars (:mod:`.real_terrain`), and PNG mosaics to look at (:mod:`.mosaic`)."""
