"""Checking a plan's promise: a simulated scan with the scanner's angular pattern
(``simulation``) and the per-face comparison written to verification.json
(``verification``)."""
