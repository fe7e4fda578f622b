"""DBToR trainer: the paper's learned primal-dual network with the breast-thickness
mask, trained on `host-sim dataset` output with the firmware's own projector
(exported as CSR by `host-sim dataset` into DIR/operator)."""
