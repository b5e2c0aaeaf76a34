"""Scene stages: from the descent trajectory and orbital terrain to the radiance field at the camera.

Read in this order: ``descent_profile`` (pose in time) -> ``terrain`` / ``resample`` (orbital I/F) ->
``node_grid`` (values on a coarse grid, interpolated) -> ``ground_mapping`` (pixel rays meet the ground)
-> ``photometry`` (I/F, sun, opposition halo) -> ``atmosphere`` / ``relief`` (optional) -> ``shadow``
(lander and parachute) -> ``heat_shield`` (in view) -> ``radiance`` (composes them: the radiance field
at one pose) -> ``motion_blur`` (how each CCD period integrates the motion, chosen in one place) ->
``blur_warp`` / ``smear_warp`` (the warp shortcuts) -> ``glint`` (the heat shield's specular glint) ->
``periods`` (radiance fields for fast flush, exposure, frame transfer).
"""
