"""OpenCV's Debevec–Malik on the 8-bit brackets that tests/hdr_debevec.rs writes.

CalibrateDebevec and MergeDebevec with OpenCV's documented defaults (samples = 70,
lambda = 10, random = false); the recovered response is passed to the merge.

Usage: python3 opencv_debevec.py WIDTH HEIGHT OUT FRAME:SHUTTER_S...
FRAME is raw interleaved 8-bit RGB, row-major; OUT gets the merged radiance as raw
little-endian float32 RGB in the same layout. Prints OpenCV's version.
"""

import sys

import cv2
import numpy as np


def main(argv):
    width, height, out = int(argv[1]), int(argv[2]), argv[3]
    images, times = [], []
    for arg in argv[4:]:
        path, shutter = arg.rsplit(":", 1)
        images.append(np.fromfile(path, dtype=np.uint8).reshape(height, width, 3))
        times.append(float(shutter))
    times = np.array(times, dtype=np.float32)
    response = cv2.createCalibrateDebevec().process(images, times)
    radiance = cv2.createMergeDebevec().process(images, times, response)
    radiance.astype("<f4").tofile(out)
    print(cv2.__version__)


if __name__ == "__main__":
    main(sys.argv)
