"""The virtual CNC: trajectory planners (ilcnc's own and LinuxCNC's), drive models and gain schedules, geometric
and cutting error sources, a whole or streamed run, and the error per command ``E(k)`` a run gives.

Public names are imported on first use (:mod:`ilcnc._lazy`); ilcnc's own modules import from the module
that owns a name.
"""

from ilcnc._lazy import lazy_exports

_EXPORTS: dict[str, tuple[str, ...]] = {
    'command_error': (
        'CommandSignal', 'PathWeightedSums', 'command_end_tangents', 'command_signal_from_run', 'error_kind',
        'measurement_gate_mm', 'path_weighted_error', 'plane_crossings', 'reference_command_samples',
        'signal_of_simulation'
    ),
    'deflection': (
        'Cutting', 'MILLING_MODES', 'MeasuredFRF', 'ModalFRF', 'Mode', 'SEED004_CUTTING_REFERENCE',
        'SEED004_MODES_REFERENCE', 'Tool', 'engagement_angles', 'feed_per_tooth_mm', 'milling_force_n', 'read_frf',
        'read_stock', 'seed004_cutting', 'seed004_tool', 'sle_frequency_domain_mm', 'sle_per_command_mm',
        'sle_time_domain_mm', 'tool_displacement_mm', 'tooth_force_n'
    ),
    'helix_sle': ('flute_radius_offsets_mm', 'sle_helical_per_command_mm', 'sle_helical_profile_mm'),
    'discrete': ('DELAY_SNAP', 'DiscreteModel', 'DriveModelError', 'FRICTION_SUBSTEP_S', 'STANDSTILL_MM', 'discrete_model'),
    'drive_loop': ('direction_normals', 'path_normals'),
    'drives': (
        'DriveStream', 'HAVE_NUMBA', 'axis_response', 'cross_coupled_response', 'filter_deviation', 'loop_response',
        'simulate_drives'
    ),
    'lifted': ('DAMPING', 'lifted_error', 'sample_fractions'),
    'lti': ('EXPM_CACHE_MAX', 'BadCoefficients', 'cont2discrete_zoh', 'expm_cache_dir', 'expm_cached', 'ss2tf', 'tf2ss'),
    'machine_errors': ('ErrorSources', 'wall_normals'),
    'plan': (
        'Reference', 'ReferenceChunk', 'check_limits', 'corner_zones_mm', 'plan_chunks', 'plan_moves', 'plan_program',
        'planned_duration_s', 'planned_move_times_s', 'profile_moves', 'vertex_tolerances_mm'
    ),
    'plan_base': ('EPS_MM', 'MAX_RUN_SAMPLES', 'PlanLimits', 'check_run_length', 'dwell_samples', 'move_directions',
                  'nominal_samples', 'nominal_speed_mm_s'),
    'plan_corners': ('BLEND_LENGTH_FRACTION', 'RoundingTables', 'junction_speeds', 'junction_tolerances', 'rounding_tables'),
    'plan_kernels': ('BLOCK_SAMPLES', 'arc_table', 'group_kernel', 'group_range', 'group_state'),
    'plan_zones': ('Pieces', 'slow_zones', 'zone_pieces'),
    'settle': ('MAX_SETTLE_S', 'settle_time_s'),
    'plan_tp': (
        'ACC_RATIO_NORMAL', 'ACC_RATIO_TANGENTIAL', 'BLEND_DIST_FRACTION', 'GAP_CYCLES', 'KINK_RATIO',
        'LOOKAHEAD_SEGMENTS', 'MIN_SEGMENT_CYCLES', 'TOLERANCE_RATIO', 'plan_linuxcnc'
    ),
    'rounding': (
        'CornerError', 'ToleranceCost', 'VertexMax', 'VertexTolerances', 'corner_errors', 'planner_rounding',
        'tolerance_cost', 'vertex_tolerances'
    ),
    'run': ('RunFigures', 'run_virtual', 'simulate_figures'),
    'schedule': ('read_schedule', 'schedule_on_samples'),
    'tighten': ('ROUNDING_SHARE', 'TIGHTER_MARKER', 'TightenedProgram', 'Tightening', 'TighterRange', 'tightened_text',
                'tightening_for', 'tolerance_block', 'tolerance_word_mm', 'own_path_control_lines'),
    'simulate': ('SimulationResult', 'desired_direction', 'simulate_program'),
    'stream': ('StreamedRun', 'simulate_streamed', 'stream_unsupported'),
    'volumetric': (
        'AxisErrorTables', 'ErrorModel', 'GridMap', 'OutsideMapError', 'SEED002_CIRCLE_CENTRE_MM',
        'SEED002_CIRCLE_RADIUS_MM', 'SyntheticMap', 'format_grid_csv', 'format_tables_csv', 'load_volumetric',
        'seed002_map'
    ),
}

__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
