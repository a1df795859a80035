"""Registration: KISS-ICP scan-to-map odometry fused with wheel odometry in an SE(2) EKF."""
