"""Blisk geometry: surfaces of revolution, blades, channels, electrodes.

Workpiece frame W: X is the blisk's rotation axis, a point at radius r and
angle theta is ``(x, r*cos(theta), r*sin(theta))``, i.e. ``theta = atan2(z, y)``.
Millimetres and radians everywhere.
"""
