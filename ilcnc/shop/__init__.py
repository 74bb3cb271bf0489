"""The shop workflow around the learning: measured logs and points checked against the program, the learning
state on disk, batches, LinuxCNC runs, reports, export and inspection.

Public names are imported on first use (:mod:`ilcnc._lazy`); ilcnc's own modules import from the module
that owns a name.
"""

from ilcnc._lazy import lazy_exports

_EXPORTS: dict[str, tuple[str, ...]] = {
    'batch': ('BatchJob', 'PartResult', 'ReturnedPart', 'ShippedPart', 'folder_programs', 'jobs_from_path',
              'learn_shipped', 'retried', 'run_batch', 'ship_part', 'summary_csv', 'write_returned'),
    'corners': (
        'CornerReport', 'DEFAULT_CORNERS', 'corner_report', 'learned_corner_report', 'setting_text',
        'write_tightened'
    ),
    'corrections': ('read_corrections', 'write_corrections'),
    'diff': (
        'ChangedLine', 'DiffInserted', 'ProgramDiff', 'WORD_KINDS', 'WordChange', 'diff_files', 'diff_programs',
        'format_diff'
    ),
    'export': ('ExportResult', 'export_program', 'output_family'),
    'fidelity': ('Fidelity', 'TARGET_CORRELATION', 'TARGET_DIFFERENCE', 'compare_signals', 'fidelity_of_log'),
    'html_report': ('DIFF_ROWS', 'HtmlFigure', 'HtmlReport', 'INSERTED_ROWS', 'IterationRow', 'WorstRow', 'render_html'),
    'gate': (
        'BASELINE_FORMAT', 'Baseline', 'ProgramCheck', 'check_program', 'expand_programs',
        'figures_line', 'judge', 'junit_xml', 'read_baseline', 'write_baseline'
    ),
    'inspect': ('InspectReport', 'command_table_csv', 'corner_rounding_warnings', 'inspect_program', 'print_report'),
    'levelling': ('LEVEL_MARKER', 'LEVEL_TOLERANCE_MM', 'MAX_ARC_PIECES', 'LevelResult', 'find_level_stamp', 'level_program'),
    'linuxcnc': (
        'DEFAULT_CONFIG_DIR', 'DEFAULT_LOCK_TIMEOUT_S', 'LinuxCNCBusyError', 'LockHolder', 'MAX_TIME_SCALE',
        'RunResult', 'linuxcnc_available', 'lock_holder', 'other_linuxcnc', 'record_run', 'run_lock', 'run_program',
        'stray_percent_line'
    ),
    'linuxcnc_config': (
        'IniFile', 'IniValue', 'ini_in', 'read_ini', 'read_ini_file', 'read_ini_text', 'scale_program_time',
        'scaled_ini_text'
    ),
    'linuxcnc_hal': ('DEFAULT_HALLIB', 'HalConfig', 'HalSetting', 'hallib_dir', 'read_hal', 'resolve_hal_file'),
    'linuxcnc_profile': (
        'LINEAR_UNITS', 'NO_JERK_M_S3', 'RESOLUTION_MM', 'AxisFromIni', 'IniProfile', 'joints_of_axes',
        'profile_from_ini', 'startup_path_control', 'write_ini_profile'
    ),
    'linuxcnc_prepare': (
        'DEFAULT_SAMPLER_DEPTH', 'PathEdit', 'PathRange', 'Preparation', 'path_ranges', 'prepare_run', 'sampler_hal'
    ),
    'path_control_edit': ('MARK', 'apply_path_edits', 'ready_program_text'),
    'log_identity': (
        'LogIdentity', 'MIN_ON_PATH_SHARE', 'check_block_numbers', 'check_log_identity', 'check_log_order',
        'log_quantum_mm', 'samples_fingerprint'
    ),
    'measure': ('Measurement', 'check_log_memory', 'interpolate_along_path', 'measure_log', 'measure_points'),
    'report': (
        'CommandDiff', 'MAX_PLOT_POINTS', 'REPORT_FILES', 'ReportRun', 'auto_magnify', 'axis_extent', 'figure_png',
        'format_factor', 'is_report_file', 'new_figure', 'plane_axes', 'write_report'
    ),
    'report_diff': ('ARROW_GRID', 'CORNER_DEG', 'CORRECTION_FILES', 'CorrectionFigures', 'correction_figures'),
    'selftest': ('SelftestResult', 'run_selftest'),
    'state': ('IterationEntry', 'LearnState', 'STATE_FILE', 'sha256_bytes', 'sha256_file', 'state_lock'),
    'state_report': ('REPORT_HTML', 'StateReport', 'WORST_ROWS', 'default_report_dir', 'write_state_report'),
    'workflow': ('LearnOutcome', 'LearnRequest', 'find_stamp', 'learn_part', 'stamp_text', 'unstamp_text'),
}

__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
