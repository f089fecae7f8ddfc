"""Device drivers: cameras (``devices.camera``) and laser relays (``devices.laser``).

Every kind of device has one contract (an abstract base with public methods that call
private ``_do_*`` hooks); real and simulated drivers subclass the same base, so the same
contract tests run against both. Drivers never import the numerics.
"""
