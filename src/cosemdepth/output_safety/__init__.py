"""Output safety: what a command may write where (output policy, input detection), atomic writes, staged output
folders replaced in one rename, and manifests of what was written."""
