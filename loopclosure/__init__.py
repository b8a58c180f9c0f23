"""Loop closure: images/descriptors -> loop-closure proposals (numpy, scikit-learn, OpenCV)."""
