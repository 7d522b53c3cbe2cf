"""The option groups several commands share: the plant over CAN, the vision system, real-time
pacing, and the bounded number types of every flag."""
