"""The flight system on a Zenoh bus, in layers; each imports only the layers before it:

``interface``  message types, topics, topology, codec
``bus``        sessions, the endpoint, replay guards, link models
``config``     deployments: strict reading and validation
``model``      deployment -> mathematics: mission model, truth backends
``flight``     the processes: environment, navigation, controller, runtime
``ground``     launcher, monitor, recording, report, faults, sweeps
``cli``        the ``ddvi`` command
"""
