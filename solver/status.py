"""Every status code a kernel or model step returns, and its text: one table for the whole solver.

Kernels return an int64 status; ``OK`` is 0 and any other value stops the run with
:func:`text` of it (:class:`solver.simulate.simulation.SimulationDiverged` adds the diagnosis).
Codes are grouped by the room that returns them: 0-9 the dynamics kernels, 10-19 the integrators,
20-29 the models, 30-39 the mass-matrix kernels.
"""
OK = 0
SINGULAR = 1             # constraint matrix not positive definite (dependent rigid members)
NONFINITE = 2            # NaN or inf appeared
NOT_CONVERGED = 3        # the position projection did not reach its tolerance
STEP_TOO_SMALL = 10      # adaptive step underflow
NEWTON_FAILED = 11       # implicit step: Newton iteration did not converge
OUT_OF_TABLE = 20        # chain1d: a prism height left the force-law table
CHAIN_CANNOT_RAMP = 21   # chain1d cannot follow a prestrain ramp
BAD_WORKSPACE = 30       # workspace too small for the mass-matrix system

TEXT = {
    OK: 'ok',
    SINGULAR: 'constraint matrix singular (degenerate rigid members)',
    NONFINITE: 'non-finite positions or velocities',
    NOT_CONVERGED: 'position projection did not converge',
    STEP_TOO_SMALL: 'adaptive step size fell below 1e-9 dt (stiff or singular motion)',
    NEWTON_FAILED: 'implicit step: Newton iteration did not converge',
    OUT_OF_TABLE: ('a prism height left the range of the force-law table (crushed flat or '
                   'overstretched: the quasi-static law has no more resistance)'),
    CHAIN_CANNOT_RAMP: ('chain1d cannot follow a prestrain ramp (its force law is precomputed '
                        'for the scene)'),
    BAD_WORKSPACE: ('workspace too small for the mass-matrix system (build it with '
                    'dynamics.workspace_for)'),
}


def text(status):
    """The text of a status code (``'status N'`` for a code not in :data:`TEXT`)."""
    return TEXT.get(int(status), f'status {status}')


# What failed and what to try, per status code (``Simulation`` adds them to the message of
# :class:`~solver.simulate.simulation.SimulationDiverged`), and the hints of its own checks.
HINT_STEP = 'try a smaller integrator.dt or another method (e.g. integrator=dopri54_projected)'
HINT_CONSTRAINT = ('use a projected method (rk4_projected, dopri54_projected) or a '
                   'smaller integrator.dt')
HINT_ENERGY = 'try a smaller integrator.dt or another method (rk4_projected, dopri54_projected)'
HINT_SLACK = ('cables went slack and the prism collapsed: raise the prestrain or lower the impact '
              'velocity')
HINT_LOCK = ('the bars of the prism crossed at the rigid-base lock: lower the impact velocity, or '
             'stop the prisms at the lock with contact.lock=penalty (divergence.bar_crossing=none '
             'lets bars pass through each other)')
HINT_LOCK_CONTACT = ('the bars of the prism crossed although contact.lock is on: raise '
                     'contact.stiffness or contact.tolerance (and lower integrator.dt)')
HINT_LOCK_BARS = ('the bars of the prism crossed although bar contact is on: lower '
                  'integrator.dt or raise contact.resolution')
DIAGNOSIS = {
    SINGULAR: ('rigid members', 'rigid members became degenerate (e.g. a rigid-base prism '
                   'driven through its lock by a fast impact): lower the impact velocity or try a '
                   'smaller integrator.dt'),
    NONFINITE: ('state', HINT_STEP),
    NOT_CONVERGED: ('constraint projection', 'try a smaller integrator.dt or a larger '
                        'integrator.projection_max_iter'),
    STEP_TOO_SMALL: ('step size', 'the motion is too stiff or singular to resolve '
                                 '(rigid-base lock, collapsed prism?): lower the impact velocity '
                                 'or loosen integrator.rtol'),
}
