"""The engine: every task, limit and controller written once over a leading world axis N.

Its classes run on one robot (a :class:`qpik.Robot`, N = 1: MuJoCo's serial calls on the
user's MjData) and on N worlds (a :class:`qpik.batch.Robot`: ``mujoco.batch`` or MuJoCo
Warp), each world the answer its own one-world run gives. :mod:`qpik.batch` is its
N-world front end.
"""
