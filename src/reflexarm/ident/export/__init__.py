"""What the user takes away from identification: the model file (:mod:`.model_file`) and a copy of the robot
file with the identified inertias and friction written back (:mod:`.write_back`)."""
