"""The command layer: what each ``safeswitch`` command does (evaluate, reproduce, render, …),
built on everything below it.

Layers, each importing only those before it: ``core`` → ``sim`` → ``leftturn`` →
``evaluation`` → ``training`` and ``report`` → ``app`` → ``cli``
(``tests/test_layers.py`` checks it).
"""
