"""The machine profile: its schema (every key range-checked at load), loading, and comment-keeping edits.

Public names are imported on first use (:mod:`ilcnc._lazy`); ilcnc's own modules import from the module
that owns a name.
"""

from ilcnc._lazy import lazy_exports

_EXPORTS: dict[str, tuple[str, ...]] = {
    'edit': ('NOTE_PREFIX', 'REMARK_PREFIX', 'format_scalar', 'update_profile', 'update_text'),
    'schema': (
        'AXIS_NAMES', 'AxisProfile', 'ControllerSection', 'DRIVE_MODELS', 'DriveModel', 'FirstOrderDelayDrive',
        'LearningSection', 'MAX_COEFFS', 'MAX_DK_CANDIDATES', 'MM_PER_INCH', 'MachineProfile', 'MachineSection',
        'MassDamperPidDrive', 'OutputSection', 'PFfFrictionDrive', 'PlannerSection', 'SPECS', 'ScheduleTuning',
        'SopdtDrive', 'Spec', 'TransferFunctionDrive', 'TuningSection', 'default_profile', 'has_position_loop',
        'load_profile', 'profile_from_dict', 'schema_markdown'
    ),
}

__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
