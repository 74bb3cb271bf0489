"""Learning: the laws that turn ``E(k)`` into corrections, the learning loop on the virtual CNC, refinement and
the feed, tuning the gains, and identifying drive models from step responses.

Public names are imported on first use (:mod:`ilcnc._lazy`); ilcnc's own modules import from the module
that owns a name.
"""

from ilcnc._lazy import lazy_exports

_EXPORTS: dict[str, tuple[str, ...]] = {
    'arc_starts': ('arc_start_constraint', 'keep_arcs_valid'),
    'cycle_hold': (
        'CLIP_CYCLE', 'HALVINGS', 'NEIGHBOUR_MOVES', 'CycleBudget', 'CycleHold', 'hold_cycle_time', 'motion_time_s',
        'slowed_moves', 'slowed_spots'
    ),
    'feed': ('FeedLaw', 'feed_cost_s', 'move_errors_mm', 'move_times_s'),
    'gain_schedule': ('DEFAULT_DK', 'ScheduleResult', 'schedule_gains', 'seed001_standin_program'),
    'guard': ('GROWTH_ABS_MM', 'GROWTH_REL', 'GROWTH_RESOLUTION_SHARE', 'LearningGuard', 'best_stats', 'grew'),
    'identification': (
        'GAIN_TOLERANCE', 'Identification', 'MODELS', 'MODEL_ALIASES', 'PARAMETERS', 'PROFILE_MODEL', 'SIGNALS',
        'UNITS'
    ),
    'identify': ('identify_step', 'sopdt_velocity_response'),
    'laws': (
        'AXES', 'LAWS', 'LearningLaw', 'PLaw', 'PidAceLaw', 'SecondOrderLaw', 'ccc_error_map', 'cut_runs',
        'first_markov_per_s', 'make_law'
    ),
    'learner': (
        'CLIP_ARC', 'CLIP_BOUND', 'CLIP_MOVE_LENGTH', 'Clip', 'IterationRecord', 'LearnResult', 'Learner',
        'UpdateShaper', 'changed_coordinates', 'clip_corrections', 'correctable_commands', 'cycle_budget',
        'frozen_reasons', 'hold_step', 'learn_virtual', 'program_with_corrections'
    ),
    'lifted_check': (
        'DEFAULT_GAMMAS', 'DEFAULT_MAX_COMMANDS', 'DEFAULT_Q_FILTERS_HZ', 'LiftedCandidate', 'LiftedCheck',
        'LiftedModel', 'check_lifted', 'lifted_model'
    ),
    'move_limits': ('ZERO_LENGTH_MM', 'keep_moves_forward', 'repeated_points', 'start_corrections', 'tie_repeated_points'),
    'refine': ('RefinePlan', 'RefineSite', 'plan_refinement', 'refine_threshold_mm'),
    'refine_tolerance': ('FLOOR_STEPS', 'MARGIN', 'TARGET_SHARE', 'ToleranceRefinement', 'plan_tolerance', 'write_tolerance'),
    'step_files': ('identify_file', 'read_step_csv'),
    'time_design': (
        'AxisDesign', 'DEFAULT_F_MAX_HZ', 'EpsilonCurve', 'LeadOption', 'TuneResult', 'design_time_domain',
        'epsilon_of', 'frequency_grid', 'learning_response'
    ),
    'tune': ('METHODS', 'TuneReport', 'tune_profile'),
}

__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
