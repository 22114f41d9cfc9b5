"""The data contract (../shared/spec/data-contract.md, version 1) in code: names, manifests, formats."""
