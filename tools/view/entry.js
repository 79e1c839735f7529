// The part of three.js that `staggered view` uses, as one global: window.THREE
// (three.module.js as it is, plus OrbitControls and the wide lines of its examples).
import * as THREE from "three";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
import { LineMaterial } from "three/examples/jsm/lines/LineMaterial.js";
import { LineSegments2 } from "three/examples/jsm/lines/LineSegments2.js";
import { LineSegmentsGeometry } from "three/examples/jsm/lines/LineSegmentsGeometry.js";

globalThis.THREE = { ...THREE, OrbitControls, LineMaterial, LineSegments2, LineSegmentsGeometry };
