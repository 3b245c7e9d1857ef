"""The jobs a user runs, as library functions (the command line calls these).

================================ ================================================================
:mod:`._demo`                    :func:`run_demo`: the main job end to end on embedded characters
================================ ================================================================
"""

from ._demo import run_demo

__all__ = ["run_demo"]
