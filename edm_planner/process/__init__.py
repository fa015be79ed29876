"""The EDM process: regimes, removed volume, erosion time, electrode wear (no rclpy).

* ``model`` -- the ``process:`` section of the machine YAML: discharge regimes (spark gap, removal rate,
  wear ratio, roughness, condition code), the finishing allowance, wear limits (defined in
  :mod:`edm_planner.cnc.process_model`, below the machine configuration that reads it; re-exported here);
* ``volume`` -- the volume of blisk material each leg removes (a voxel field, with a certified bracket);
* ``report`` -- erosion time, electrode wear and electrodes needed, per electrode, channel and blisk;
* ``set_process`` -- the process of a designed electrode set: roughing twins and their proof, the report,
  wear compensation (the ``process_step`` of :class:`~edm_planner.machining.electrode_set.SetDesigner`).

``process`` lies above ``machining`` (it uses the removal proof and the designed set) and above
``machine``; neither imports it.
"""
