// Placeholder until the calibration library lands (issue 15).
