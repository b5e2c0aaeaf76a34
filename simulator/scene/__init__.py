"""Scene stages: from the descent trajectory and orbital terrain to the radiance field at the camera.

Read in this order: ``descent_profile`` (pose in time) -> ``terrain`` / ``resample`` (orbital I/F) ->
``ground_mapping`` (pixel rays meet the ground) -> ``photometry`` (I/F, sun, opposition halo) ->
``shadow`` (lander and parachute) -> ``heat_shield`` (in view, glint) -> ``motion_blur`` (sub-poses
per period) -> ``radiance`` (composes them: radiance fields for fast flush, exposure, frame transfer).
"""
