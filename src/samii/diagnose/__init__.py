"""samii.diagnose"""
