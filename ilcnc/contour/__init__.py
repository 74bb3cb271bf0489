"""The programmed path and the exact contour error of positions against it; which moves cut and which are in the
air.

Public names are imported on first use (:mod:`ilcnc._lazy`); ilcnc's own modules import from the module
that owns a name.
"""

from ilcnc._lazy import lazy_exports

_EXPORTS: dict[str, tuple[str, ...]] = {
    'air': (
        'CuttingRule', 'MOVE_AIR', 'MOVE_CUT', 'MOVE_NOT_FED', 'air_above_mm', 'air_command_mask', 'air_commands',
        'cutting_rule', 'cutting_samples', 'move_classes', 'profile_cutting_rule', 'profile_move_classes',
        'rule_air_commands'
    ),
    'estimates': ('CommandError', 'per_command_error', 'sample_command', 'summary', 'tangent_error'),
    'figures': ('ErrorFigures',),
    'surface': ('arc_height_error_mm', 'line_split_fractions', 'surface_height_mm'),
    'path': ('FAR_MM', 'PathGeometry', 'TWO_PI', 'WorkBuffers'),
    'search': ('ContourError', 'DEFAULT_CHUNK', 'DEFAULT_WINDOW', 'REACH_FACTOR', 'contour_error', 'guess_hints'),
}

__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
