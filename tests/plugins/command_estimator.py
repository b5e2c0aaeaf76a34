"""A small external-command estimator for the plugin tests (run as a program, never imported).

    python command_estimator.py MODE MEASUREMENTS.json FLAT_FIELD PARAMETERS.json OUTPUT.json IMAGE...

MODE ok: velocity = IMU velocity at the last image minus ``parameters["bias"]``; features[k] carries
image k's mean DN as brightness_dn and the flat field's mean (-1 without one) as contrast_dn, so the
test can check what arrived through the files. Other modes break the contract on purpose: missing,
wrong_type, exit, no_output, bad_json, sleep, sleep_with_child (a grandchild that must die too), segfault.
"""
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np


def read_image(path):
    if path.endswith(".npy"):
        return np.load(path)
    if path.endswith(".png"):
        import cv2

        return cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if path.endswith(".tif"):
        from PIL import Image

        return np.asarray(Image.open(path))
    if path.endswith(".fits"):
        from astropy.io import fits

        return fits.getdata(path)
    return np.fromfile(path, dtype="<u2")


def main():
    mode, measurements_path, flat_path, parameters_path, output, *images = sys.argv[1:]
    measurements = json.load(open(measurements_path))
    parameters = json.load(open(parameters_path))
    if mode == "exit":
        print("flight estimator: cannot lock the camera model", file=sys.stderr)
        sys.exit(3)
    if mode == "segfault":
        os.kill(os.getpid(), signal.SIGSEGV)
    if mode in ("sleep", "sleep_with_child"):
        if mode == "sleep_with_child":
            child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
            with open(parameters["pid_file"], "w") as handle:
                handle.write(str(child.pid))
        time.sleep(120)
    if mode == "no_output":
        return
    if mode == "bad_json":
        open(output, "w").write("{not json")
        return
    last = measurements["images"][-1]["imu_velocity_mps"]
    bias = parameters.get("bias", [0.0, 0.0])
    flat_mean = -1.0 if flat_path == "none" else float(np.mean(read_image(flat_path)))
    result = {"velocity_east_mps": last[0] - bias[0], "velocity_north_mps": last[1] - bias[1], "valid": True,
              "reason": "ok", "features": [{"brightness_dn": float(np.mean(read_image(p))), "contrast_dn": flat_mean}
                                           for p in images],
              "diagnostics": {"note": "extra keys are ignored"}}
    if mode == "missing":
        del result["reason"]
    if mode == "wrong_type":
        result["valid"] = "yes"
    json.dump(result, open(output, "w"))


if __name__ == "__main__":
    main()
