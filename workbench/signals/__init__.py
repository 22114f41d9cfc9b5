"""Signal processing on in-memory arrays and frames: filters, derivatives, flow-speed interpolation."""
