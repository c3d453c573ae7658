"""A signer that can be read: an imitation run's performance in its source's keypoints, scored
against the person (docs/signing.md)."""
