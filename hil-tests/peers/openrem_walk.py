#!/usr/bin/env python3
"""Read a dose SR (TID 10001) the way a dose registry's importer does.

OpenREM's RDSR importer (remapp/extractors/rdsr.py, the functions
`_irradiationeventxraydata` and `_irradiationeventxraysourcedata`,
`_accumulatedmammoxraydose`) reads each irradiation event's content items
with pydicom by the concept name's Code Meaning: numeric items through
`MeasuredValueSequence[0].NumericValue`, coded ones through
`ConceptCodeSequence[0]`, and, for a CONTAINER whose meaning is
"Mammography CAD Breast Composition", each child through the attribute
`ConceptNamesCodes`, which no DICOM data set has (the keyword is
`ConceptNameCodeSequence`): pydicom raises AttributeError there, so a
conforming breast-composition container makes the import of the report
fail. This walk is our own transcription of those rules, kept to what they
read, so that a test can check our dose SR against them.

Usage: openrem_walk.py DOSE_SR.dcm [--with-composition-container]
Prints JSON: {"events": [{meaning: value, ...}], "accumulated_agd": [...],
"composition_containers": N}; with --with-composition-container a
conforming TID 4007-style container (Breast Composition, Percent
Fibroglandular Tissue) is added to the first event before the walk, to show
what the importer does with one. A walk that fails prints {"error": ...} and
exits 3.
"""
import json
import sys

import pydicom
from pydicom.dataset import Dataset
from pydicom.sequence import Sequence


def meaning(item):
    return item.ConceptNameCodeSequence[0].CodeMeaning


NUMERIC = {
    "Average Glandular Dose",
    "Entrance Exposure at RP",
    "Half Value Layer",
    "KVP",
    "Exposure",
    "Exposure Time",
    "Compression Thickness",
    "Compression Force",
    "Positioner Primary Angle",
    "Positioner Primary End Angle",
}
CODED = {"Irradiation Event Type", "Acquisition Plane", "Anode Target Material", "Target Region"}


def event(item):
    e = {"composition": None}
    for cont in item.ContentSequence:
        m = meaning(cont)
        if m in NUMERIC:
            e[m] = float(cont.MeasuredValueSequence[0].NumericValue)
        elif m in CODED:
            e[m] = cont.ConceptCodeSequence[0].CodeMeaning
        elif m == "X-Ray Filters":
            for c2 in cont.ContentSequence:
                if meaning(c2) == "X-Ray Filter Material":
                    e["X-Ray Filter Material"] = c2.ConceptCodeSequence[0].CodeMeaning
        elif m == "Irradiation Event UID":
            e[m] = str(cont.UID)
        if cont.ValueType == "CONTAINER" and m == "Mammography CAD Breast Composition":
            # As the importer reads it (see the module's documentation).
            for cont2 in cont.ContentSequence:
                if cont2.ConceptNamesCodes[0].CodeMeaning == "Breast Composition":
                    e["composition"] = cont2.CodeValue
                elif cont2.ConceptNamesCodes[0].CodeMeaning == "Percent Fibroglandular Tissue":
                    e["percent_fibroglandular_tissue"] = cont2.NumericValue
    return e


def code(value, scheme, text):
    c = Dataset()
    c.CodeValue, c.CodingSchemeDesignator, c.CodeMeaning = value, scheme, text
    return c


def composition_container():
    """A breast-composition container as TID 4007 shapes it."""
    comp = Dataset()
    comp.RelationshipType, comp.ValueType = "CONTAINS", "CODE"
    comp.ConceptNameCodeSequence = Sequence([code("129714008", "SCT", "Breast Composition")])
    comp.ConceptCodeSequence = Sequence([code("129716005", "SCT", "Scattered fibroglandular densities")])
    pft = Dataset()
    pft.RelationshipType, pft.ValueType = "CONTAINS", "NUM"
    pft.ConceptNameCodeSequence = Sequence([code("111046", "DCM", "Percent Fibroglandular Tissue")])
    mv = Dataset()
    mv.NumericValue = "12.5"
    mv.MeasurementUnitsCodeSequence = Sequence([code("%", "UCUM", "%")])
    pft.MeasuredValueSequence = Sequence([mv])
    box = Dataset()
    box.RelationshipType, box.ValueType, box.ContinuityOfContent = "CONTAINS", "CONTAINER", "SEPARATE"
    # The importer matches the container by its Code Meaning alone; the
    # code here is ours (99DBTOR), the meaning the one it looks for.
    box.ConceptNameCodeSequence = Sequence([code("MCADBC", "99DBTOR", "Mammography CAD Breast Composition")])
    box.ContentSequence = Sequence([comp, pft])
    return box


def walk(path, inject):
    ds = pydicom.dcmread(path)
    events, accumulated, containers = [], [], 0
    for item in ds.ContentSequence:
        if item.ValueType != "CONTAINER":
            continue
        if meaning(item) == "Irradiation Event X-Ray Data":
            if inject and not events:
                item.ContentSequence.append(composition_container())
            containers += sum(
                1
                for c in item.ContentSequence
                if c.ValueType == "CONTAINER" and meaning(c) == "Mammography CAD Breast Composition"
            )
            events.append(event(item))
        elif meaning(item) == "Accumulated X-Ray Dose Data":
            for c in item.ContentSequence:
                if meaning(c) == "Accumulated Average Glandular Dose":
                    accumulated.append(float(c.MeasuredValueSequence[0].NumericValue))
    return {"events": events, "accumulated_agd": accumulated, "composition_containers": containers}


def main(args):
    if not args or args[0].startswith("-"):
        sys.exit(__doc__)
    try:
        out = walk(args[0], "--with-composition-container" in args[1:])
    except (AttributeError, IndexError, KeyError) as e:
        print(json.dumps({"error": f"{type(e).__name__}: {e}"}))
        sys.exit(3)
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1:])
