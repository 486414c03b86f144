"""Model discrepancy: which of the model extensions (`sgdr.physics.extensions`) a sequence asks
for, fitted from a finished run and judged on data the fit did not see (`sgdr.discrepancy.run`)."""
