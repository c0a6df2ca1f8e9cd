"""refsim: an independent reference simulator of the brake-2dof, drum-pendulum and belt-ndof rigs (tests only).

Why it exists (issue 13): diagnosis was only ever tested on recordings from our own
simulator (daq/physics + daq/sim), with every hidden effect in exactly the form the
effects catalog fits. Real rigs carry effects in other forms, several at once, on
rigs a few per cent off their config. This package writes such recordings: the rigs'
physics from the papers (paper 001's Lagrangian and eqs. 5-7, 11; paper 002's eqs.
1 and 3), integrated with scipy's adaptive ``solve_ivp``, with hidden effects in
published forms *other* than the catalog's (Dieterich logarithmic aging, friction
keyed to the body's acceleration, Arrhenius temperature dependence, a second-order
belt drive with ripple, power-law force-rate, surface waviness off the catalog, a
spring off its config value) and its own instruments (noise, quantisation, hold,
spikes, clock jitter). Output: the interchange CSV that ``daq`` reads plus a JSON
sidecar with the truth.

Why it shares no code with daq: a recording that reuses daq's equations, friction
terms, integrator or sensor models would share their mistakes and conventions, and
a diagnosis could pass because model and data are the same code. Here nothing is
imported from ``daq``, ``drivers`` or ``sim_backends`` (a test checks it); only the
rig config TOML files are read, as data, with ``tomllib``. Agreement with daq is
*measured* (tests/test_refsim.py): the null case, with nothing hidden, must match
our simulator in what the papers fix and be explained by daq's seed model to within
the noise.

Modules: :mod:`.brake`, :mod:`.drum`, :mod:`.belt` (rigs; belt-ndof: paper 000's chain of 1-3
masses in the belt's frame, elongations and slip speeds, on velocity steps), :mod:`.slider` (a
lab-frame spring-slider), :mod:`.effects` (config, drive programmes, effect forms), :mod:`.sensors`
(instruments), :mod:`.make` (command line:
``python tests/refsim/make.py brake-2dof --effect stick-log:b=0.05 -o out.csv``;
``python tests/refsim/make.py belt-ndof --steps 0.2:5,0.06:5,0.2:5 --effect accel-body:amp=0.1 -o b.csv``).
"""
