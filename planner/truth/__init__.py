"""Checking a plan's promise after it is made.

Takes a written plan and the model; gives a simulated scan with the scanner's angular
pattern (``simulation``) and the per-face comparison written to verification.json
(``verification``).
"""
