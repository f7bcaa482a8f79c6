"""The flight processes: the service runtime every process shares, the environment (truth,
clock, exostate), navigation, the controller (the pure control law apart from its process) and
the one-process baseline that runs the same code without a bus.

May import: ``ddvi_core`` and every library layer (``services.interface``, ``services.bus``,
``services.config``, ``services.model``). Not ``services.ground``. Each process module is
imported by its module path; this package re-exports nothing.
"""
