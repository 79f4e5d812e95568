"""samii.design"""
