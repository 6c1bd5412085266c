"""The tools built on the library: the ``zenoh-robot`` CLI, launch, bench, the lossy-link experiment,
stream metrics and recorders. Imported only on purpose: ``import zenoh_robot`` loads none of them.
"""
