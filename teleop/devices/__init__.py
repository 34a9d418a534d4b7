"""Robot-side devices, one family per module, each with a simulated backend in the package.

==============  ===============================  =========================================
family          open with                        backends (``BACKENDS`` in the module)
==============  ===============================  =========================================
gripper         ``gripper.make_gripper``         ``sim`` (playback), ``franky``
tactile camera  ``camera.make_camera``           ``sim`` (playback), ``opencv``
load cell       ``loadcell.make_load_cell``      ``sim`` (playback), ``serial``, ``tcp``
==============  ===============================  =========================================

Every device has the lifecycle of :class:`teleop.devices.base.Device`. Backends are
imported when opened, and this package imports nothing on its own, so the HX711 bridge
(:mod:`teleop.devices.hx711_bridge`) runs on a Raspberry Pi with the standard library.
"""
