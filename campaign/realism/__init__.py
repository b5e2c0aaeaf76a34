"""Tools that combine the simulator side with the estimator side to judge realism: terrain statistics
with the estimator's parameters, the real-Mars reference ranges, and ``campaign compare-flight``
(simulated vs flight descent images, the paper's Table 3 metrics)."""
