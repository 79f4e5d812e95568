"""samii.identify"""
