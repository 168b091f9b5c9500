"""What any model does with images: locate pixels on the ground, orthorectify, image motion, PSFs."""
