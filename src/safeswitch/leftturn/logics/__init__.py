"""The left turn's switching logics, each written once over any number of conflicts:
``paper`` (Algorithm 1 as its text describes it, :mod:`.paper`), ``certified`` (a Simplex-style
safety filter with a proof, :mod:`.certified`) and ``guarded`` (the first with the second
beneath it). They are registered plugins (entry-point group ``safeswitch.logics``); a factory
receives the scene (:class:`~safeswitch.leftturn.views.LogicScene`) and the logic sees a
:class:`~safeswitch.leftturn.views.ConflictView` each tick."""
