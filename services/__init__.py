"""The flight system on a Zenoh bus, in layers; each imports only the layers before it:

``interface``  message types, topics, topology, codec
``bus``        sessions, the endpoint, replay guards, link models
``config``     deployments: strict reading and validation
``model``      deployment -> mathematics: mission model, truth backends
``flight``     the processes: environment, navigation, controller, runtime
``ros2``       the ROS 2 wire format; its ``gateway``, the service that shows a run to ROS 2
``ground``     launcher, monitor, recording, report, faults, sweeps
``cli``        the ``ddvi`` command
"""
