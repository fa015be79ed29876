"""The EDM process: regimes, removed volume, erosion time, electrode wear (no rclpy).

* ``model`` -- the ``process:`` section of the machine YAML: discharge regimes (spark gap, removal rate,
  wear ratio, roughness, condition code), the finishing allowance, wear limits;
* ``volume`` -- the volume of blisk material each leg removes (a voxel field, with a certified bracket);
* ``report`` -- erosion time, electrode wear and electrodes needed, per electrode, channel and blisk.
"""
