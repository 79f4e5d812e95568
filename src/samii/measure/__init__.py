"""samii.measure"""
