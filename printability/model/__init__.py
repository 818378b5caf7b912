"""The model: the conventions every stage shares, layers, nozzles and their shapes, machines.

The modules: :mod:`.geometry` (the conventions every module follows, and the planar
types), :mod:`.layers` (:class:`~printability.model.layers.LayerStack`),
:mod:`.nozzle` (:func:`~printability.model.nozzle.parse_nozzle`, footprints), :mod:`.shapes`
(the orifice shapes) and :mod:`.machine` (:func:`~printability.model.machine.parse_machine`:
kinematics, rotary axis, bed, limits).
"""
