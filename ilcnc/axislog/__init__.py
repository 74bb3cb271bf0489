"""Axis logs and measured points: the machine's record of a run, read from ilcnc CSV, LinuxCNC halsampler and
Heidenhain TNCscope files, and probe or CMM points.

Public names are imported on first use (:mod:`ilcnc._lazy`); ilcnc's own modules import from the module
that owns a name.
"""

from ilcnc._lazy import lazy_exports

_EXPORTS: dict[str, tuple[str, ...]] = {
    'detect': ('LOG_FORMATS', 'detect_log_format', 'estimate_log_samples', 'read_log'),
    'heightmap': ('HEIGHT_MAP_FORMATS', 'HeightMap', 'detect_height_map', 'read_height_map'),
    'halsampler': ('HALSAMPLER_COLUMNS', 'commands_from_lines', 'halsampler_column_map', 'moves_from_lines', 'read_halsampler'),
    'log': (
        'AXIS_LOG_HEADER', 'AxisLog', 'check_sample_times', 'decode_text', 'format_axis_log', 'norm_unit',
        'read_axis_log', 'write_axis_log'
    ),
    'points': ('MeasuredPoints', 'read_points'),
    'tncscope': ('LENGTH_UNITS_MM', 'TNCSCOPE_COLUMNS', 'read_tncscope', 'split_unit'),
}

__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
