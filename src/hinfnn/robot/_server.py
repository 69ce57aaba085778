"""The server process of :class:`hinfnn.robot.VirtualRobot` (``python -m hinfnn.robot._server``):
its configuration pickled on stdin (:func:`hinfnn.robot.virtual.serve`)."""

import pickle
import sys

from hinfnn.robot.virtual import serve

if __name__ == "__main__":
    serve(pickle.load(sys.stdin.buffer))
