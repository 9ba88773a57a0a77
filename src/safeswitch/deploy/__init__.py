"""Out of the lab: a trained controller exported to ONNX with its switch's parameters (what
:mod:`safeswitch.runtime` runs without the training stack), and scenarios written as
OpenSCENARIO. Needs the ``deploy`` extra (``onnx``, ``onnxruntime``, ``scenariogeneration``)."""
