"""The application layer: the command line, batches (local and Ray), output files, evaluation
against ground truth, the benchmark and the demo. It resolves a method once, then calls
:mod:`stereojax.inference`; nothing below it imports it. Import the modules themselves."""

