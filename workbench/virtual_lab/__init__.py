"""The virtual lab: a water tunnel and a towing tank that write campaign folders per data contract v1.

Physics richer than the models under test (``physics.TrueLegModel``), a rig with its own clocks,
noise, bias and drift (``rig``), named injectable effects (``effects``), and writers for the three
raw forms (``writers``). Entry points: ``tunnel.generate_tunnel`` and ``towing.generate_towing``;
every generated folder also holds ``truth.json`` with the ground truth.
"""
