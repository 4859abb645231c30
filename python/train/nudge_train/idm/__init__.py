"""IDM car-following fitted to real NGSIM data, real cut-ins, and the IDM world's intrusion rule.

Modules: ``model`` (IDM, simulators), ``sources`` (files and the pipeline's splits), ``pairs``
(leader-follower records), ``fit`` (calibration), ``cutins`` (events and reactions), ``yielding``
(the intrusion rule), ``pipeline`` (the stages), ``report``. Entry point: ``nudge-train idm``.
"""
