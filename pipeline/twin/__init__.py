"""The hardware twin: a separate process that plays the robots' ROS 2 drivers with a reality of its own.

Its physics, sensor and network errors come from a reality profile (``profiles/*.yaml``) that
the training side never reads. Start it with ``python -m pipeline.twin --fleet <fleet> --profile
<profile>``; the deploy stage starts it itself when the fleet file says ``target: twin``.
"""
