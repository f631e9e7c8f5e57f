"""The real runtime: ramps nodes and clients over Zenoh.

It drives the same ``ramps.core`` objects as the simulator; everything here
is I/O: the Zenoh session, worker processes, the load publisher's
measurements, the Prometheus metrics a node serves, the Team API's
futures. No placement or recovery decision is made in this package.
"""
