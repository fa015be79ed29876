"""Parametric blades: the former home of the quintic sections stacked from hub to shroud.

Kept so that old imports work; the code lives in one module per concern:

* :mod:`.parametric_quintic`: the quintic side, :func:`~.parametric_quintic.quintic_coefficients`
  (Liu Yuting et al. 2024, eq. 3-5);
* :mod:`.parametric_outline`: one section in the unrolled plane,
  :func:`~.parametric_outline.tangent_point`, :func:`~.parametric_outline.section_outline`
  (:class:`~.parametric_outline.SectionOutline`), the designer's
  :class:`~.parametric_outline.SectionDefinition` and
  :func:`~.parametric_outline.definition_outline`;
* :mod:`.parametric_stacking`: :func:`~.parametric_stacking.interpolate_definitions`
  along the span and :func:`~.parametric_stacking.stack_sections` between hub and shroud;
* :mod:`.parametric_yaml`: the ``blade: parametric:`` schema,
  :func:`~.parametric_yaml.parse_parametric` and ``SPAN_EXTENSION``.
"""

from .parametric_outline import (SectionDefinition, SectionOutline, definition_outline, section_outline,
                                 tangent_point)
from .parametric_quintic import quintic_coefficients
from .parametric_stacking import interpolate_definitions, stack_sections
from .parametric_yaml import SPAN_EXTENSION, parse_parametric

__all__ = ["quintic_coefficients", "tangent_point", "SectionOutline", "section_outline",
           "SectionDefinition", "definition_outline", "interpolate_definitions", "stack_sections",
           "parse_parametric", "SPAN_EXTENSION"]
