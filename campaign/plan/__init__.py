"""Planning: where each case's trajectory lies on its class's terrain strip (:mod:`.placement`), and
whether the terrain can hold the images' footprints (:mod:`.coverage`)."""
