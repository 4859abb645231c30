"""Adapters that put nudge into other people's simulators.

- :mod:`nudge.adapters.highway`: nudge as the controller of the ego in highway-env
  (``highway-v0``, ``highway-fast-v0``); needs the ``highway`` extra
  (``pip install "nudge-planner[highway]"``). See docs/highway_env.md.

Each adapter is imported on its own: ``import nudge`` does not import the simulators.
"""
