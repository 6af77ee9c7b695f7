"""`launcher test`: rostest's runner (`runner`) and its JUnit results (`results`)."""
