"""The machine profile: its schema (every key range-checked at load), loading, and comment-keeping edits.

Public names are imported on first use (:mod:`ilcnc._lazy`); ilcnc's own modules import from the module
that owns a name.
"""

from ilcnc._lazy import lazy_exports

_EXPORTS: dict[str, tuple[str, ...]] = {
    'docs': ('schema_markdown',),
    'edit': ('NOTE_PREFIX', 'REMARK_PREFIX', 'format_scalar', 'update_profile', 'update_text'),
    'load': ('default_profile', 'load_profile', 'profile_from_dict'),
    'schema': (
        'AXIS_NAMES', 'DEFAULT_ERROR', 'DRIVE_KEY', 'ERROR_KINDS', 'HISTORY_LAWS', 'MAX_COEFFS', 'MAX_DK_CANDIDATES',
        'MM_PER_INCH', 'PREDICTED_ERRORS', 'SELECTORS', 'SPECS', 'Spec', 'TOP_SECTIONS', 'default_of',
        'format_number', 'spec_of'
    ),
    'sections': (
        'AxisProfile', 'ControllerSection', 'DRIVE_MODELS', 'DriveModel', 'FirstOrderDelayDrive', 'LearningSection',
        'MODE_KEYS', 'MachineProfile', 'MachineSection', 'MassDamperPidDrive', 'OutputSection', 'PFfFrictionDrive',
        'PlannerSection', 'ProfileDumper', 'ScheduleTuning', 'SopdtDrive', 'TransferFunctionDrive', 'TuningSection',
        'has_position_loop'
    ),
}

__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
