"""OpenCV's Debevec–Malik on the 8-bit brackets that tests/bracket writes.

CalibrateDebevec and MergeDebevec with OpenCV's documented defaults (samples = 70,
lambda = 10, random = false); the recovered response is passed to the merge.

Usage: python3 opencv_debevec.py BRACKET [-- BRACKET]...
with BRACKET = WIDTH HEIGHT OUT FRAME:SHUTTER_S...
FRAME is raw interleaved 8-bit RGB, row-major; OUT gets the merged radiance as raw
little-endian float32 RGB in the same layout. Brackets are merged one after the other in
one process. Prints OpenCV's version.
"""

import sys

import cv2
import numpy as np


def merge(args):
    width, height, out = int(args[0]), int(args[1]), args[2]
    images, times = [], []
    for arg in args[3:]:
        path, shutter = arg.rsplit(":", 1)
        images.append(np.fromfile(path, dtype=np.uint8).reshape(height, width, 3))
        times.append(float(shutter))
    times = np.array(times, dtype=np.float32)
    response = cv2.createCalibrateDebevec().process(images, times)
    radiance = cv2.createMergeDebevec().process(images, times, response)
    radiance.astype("<f4").tofile(out)


def main(argv):
    bracket = []
    for arg in argv[1:] + ["--"]:
        if arg == "--":
            merge(bracket)
            bracket = []
        else:
            bracket.append(arg)
    print(cv2.__version__)


if __name__ == "__main__":
    main(sys.argv)
