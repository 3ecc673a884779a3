"""Chained-form (Samson) path-following steering law (seed 002): core chained_form.py, FMU
AgvChainedForm.
"""
