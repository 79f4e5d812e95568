"""samii.viz"""
