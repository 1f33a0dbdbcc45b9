"""glmav-sitl: a software-in-the-loop simulator of the GLMAV that speaks MAVLink 2."""
