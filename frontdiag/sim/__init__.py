"""frontdiag.sim"""
